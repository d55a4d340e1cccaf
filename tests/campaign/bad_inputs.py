#!/usr/bin/env python3
"""The bad-input campaign: hundreds of invalid or absurd inputs, each given to the
`objslam` command that reads it, each outcome classified.

Every input here is invalid by the documented format or range, so the only good outcome is
a clean error: a non-zero exit whose message names the file (or flag) and the field. The
other outcomes are counted per input kind:

  clean     refused, naming the file or flag and the field
  unnamed   refused, but the message misses the file or the field
  warned    exit 0 with a warning
  accepted  exit 0 without a warning: a bad value silently accepted
  panic     a Rust panic, or death by a signal (stack overflow, abort)
  hang      still running after --timeout seconds
  memory    resident memory above --max-rss-mb

Before the bad inputs, the unedited inputs are run through the same commands and must
succeed, so that a refusal for an unrelated reason cannot pass for a clean one.

Needs Python 3.11 or later (tomllib). Usage (from the repository root, after `cargo build
--release`):

    python3 tests/campaign/bad_inputs.py [--bin target/release/objslam] [--work DIR]
        [--kinds scenario,csv,...] [--json OUT.json]

It prints a table per kind and lists every case that is not clean. Only the standard
library is used. docs/guide/fuzzing.md says how this relates to the fuzzing harness.
"""

import argparse
import json
import math
import os
import random
import re
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
import tomllib
import zlib

OUTCOMES = ["clean", "unnamed", "warned", "accepted", "panic", "hang", "memory"]


class Case:
    def __init__(self, kind, label, args, names, files=None):
        self.kind = kind
        self.label = label
        self.args = args
        # Strings the error must contain: the file (or flag) and the field; a tuple holds
        # alternatives.
        self.names = names
        # Files to write first: {path: bytes or str}.
        self.files = files or {}


def run_case(binary, case, timeout, max_rss_mb, cwd):
    for path, content in case.files.items():
        os.makedirs(os.path.dirname(path), exist_ok=True)
        mode = "wb" if isinstance(content, bytes) else "w"
        with open(path, mode) as f:
            f.write(content)
    env = dict(os.environ, RUST_BACKTRACE="0", OBJSLAM_CACHE=os.path.join(cwd, "cache"))
    start = time.time()
    # stderr goes to a file: a pipe nobody reads until the end would stall a chatty command.
    err_file = tempfile.TemporaryFile()
    p = subprocess.Popen(
        [binary] + case.args, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=err_file,
        start_new_session=True,
    )
    outcome = None
    peak = 0
    while True:
        if p.poll() is not None:
            break
        try:
            with open(f"/proc/{p.pid}/status") as f:
                for line in f:
                    if line.startswith("VmRSS:"):
                        peak = max(peak, int(line.split()[1]) // 1024)
        except OSError:
            pass
        if peak > max_rss_mb:
            outcome = "memory"
        elif time.time() - start > timeout:
            outcome = "hang"
        if outcome:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
            break
        time.sleep(0.02)
    err_file.seek(0)
    stderr = err_file.read().decode("utf-8", "replace")
    if outcome is None:
        code = p.returncode
        if "panicked at" in stderr or code < 0 or code == 101:
            outcome = "panic"
        elif code == 0:
            outcome = "warned" if "warning" in stderr.lower() else "accepted"
        elif all(any(named(a, stderr) for a in (n if isinstance(n, tuple) else (n,))) for n in case.names):
            outcome = "clean"
        else:
            outcome = "unnamed"
    return outcome, stderr.strip().splitlines()[-1:] if stderr.strip() else [], time.time() - start


def named(name, text):
    """Whether `text` names `name` as a word (a field `x` is not named by any word with an x)."""
    word = re.compile(r"[A-Za-z0-9_]")
    left = r"(?<![A-Za-z0-9_])" if word.match(name[0]) else ""
    right = r"(?![A-Za-z0-9_])" if word.match(name[-1]) else ""
    return re.search(left + re.escape(name) + right, text) is not None


# ---------------------------------------------------------------- TOML settings edits


def toml_literal(v):
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, list):
        return "[" + ", ".join(toml_literal(x) for x in v) + "]"
    return str(v)


# Settings whose valid values include negative numbers.
SIGNED = ("mount_xyz_m", "mount_yaw_deg", "mount_pitch_deg", "bearing_deg", "turn_deg", "tilt_deg", "mount_y")


def numeric_lines(text):
    """(line index, table, key, value) of every uncommented numeric setting."""
    table = ""
    out = []
    for i, raw in enumerate(text.splitlines()):
        line = raw.split("#")[0].strip()
        if line.startswith("[") and line.endswith("]"):
            table = line.strip("[] ")
            continue
        m = re.match(r"^([a-z_0-9]+) = (.+)$", line)
        if not m:
            continue
        try:
            value = tomllib.loads(f"v = {m.group(2)}")["v"]
        except tomllib.TOMLDecodeError:
            continue
        numeric = lambda x: isinstance(x, (int, float)) and not isinstance(x, bool)
        if numeric(value) or (isinstance(value, list) and value and all(numeric(x) for x in value)):
            out.append((i, table, m.group(1), value))
    return out


def bad_values(table, key, value):
    signed = key in SIGNED
    def scalar(x):
        if isinstance(x, float):
            vals = [math.nan, math.inf, -math.inf]
            if not signed and x >= 0:
                vals.append(-1.0)
            return vals
        vals = [-1]
        # Seeds take any value, and a pass bound no run reaches says what leaving it out
        # says; every other count has an upper bound. 1e9 fits a u32 field, 4e12 does not.
        if not key.endswith("seed") and table != "pass":
            vals += [1_000_000_000, 4_000_000_000_000]
        return vals if not signed else []
    if isinstance(value, list):
        out = []
        for k, x in enumerate(value):
            for b in scalar(x):
                v = list(value)
                v[k] = b
                out.append(v)
        return out
    return scalar(value)


def edited(text, line, key, value):
    lines = text.splitlines()
    lines[line] = f"{key} = {toml_literal(value)}"
    return "\n".join(lines) + "\n"


def table_of(text, prefix):
    """The tables under `prefix` of a scenario text, as a file of their own."""
    out = []
    keep = False
    for raw in text.splitlines():
        line = raw.strip()
        if line.startswith("[") and line.endswith("]"):
            name = line.strip("[] ")
            keep = name == prefix or name.startswith(prefix + ".")
            if keep and name != prefix:
                out.append("[" + name[len(prefix) + 1:] + "]")
            continue
        if keep and line and not line.startswith("#"):
            out.append(line)
    return "\n".join(out) + "\n"


def settings_cases(kind, text, file, command):
    cases = []
    for line, table, key, value in numeric_lines(text):
        # An array one element longer than its field (toml's reader alone drops the extra).
        longer = [value + [value[-1]]] if isinstance(value, list) else []
        for bad in bad_values(table, key, value) + longer:
            cases.append(Case(kind, f"{table + '.' if table else ''}{key} = {toml_literal(bad)}",
                              [a.replace("FILE", file) for a in command], [os.path.basename(file), key],
                              {file: edited(text, line, key, bad)}))
    return cases


# ---------------------------------------------------------------- JSON edits


def json_paths(v, path=()):
    """Every leaf's path."""
    if isinstance(v, dict):
        for k, x in v.items():
            yield from json_paths(x, path + (k,))
    elif isinstance(v, list):
        for k, x in enumerate(v[:3]):
            yield from json_paths(x, path + (k,))
    else:
        yield path


def set_path(v, path, new):
    v = json.loads(json.dumps(v))
    node = v
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = new
    return v


def path_name(path):
    """The last named field of a path (what an error should name)."""
    return [p for p in path if isinstance(p, str)][-1]


def json_type_cases(kind, doc, file, command, limit, rng):
    """Each of `limit` random leaves set to a string where a number belongs, or a number
    where a string belongs."""
    paths = [p for p in json_paths(doc) if p]
    rng.shuffle(paths)
    cases = []
    for path in paths[:limit]:
        node = doc
        for p in path:
            node = node[p]
        if node is None or isinstance(node, bool):
            continue
        new = "x" if not isinstance(node, str) else 12345
        cases.append(Case(kind, f"{'.'.join(map(str, path))} = {json.dumps(new)}", command,
                          [os.path.basename(file), path_name(path)], {file: json.dumps(set_path(doc, path, new))}))
    return cases


def corrupt_file_cases(kind, content, file, command):
    data = content if isinstance(content, bytes) else content.encode()
    return [
        Case(kind, "empty file", command, [os.path.basename(file)], {file: b""}),
        Case(kind, "truncated to half", command, [os.path.basename(file)], {file: data[: len(data) // 2]}),
        Case(kind, "random bytes", command, [os.path.basename(file)],
             {file: bytes(random.Random(7).getrandbits(8) for _ in range(2000))}),
    ]


# ---------------------------------------------------------------- PNG


def png_chunk(tag, data):
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)


def png(width, height, rows=None):
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    raw = rows if rows is not None else b"".join(b"\0" + b"\x40" * (3 * width) for _ in range(height))
    return b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", ihdr) + png_chunk(b"IDAT", zlib.compress(raw)) + png_chunk(b"IEND", b"")


# ---------------------------------------------------------------- fixtures


def sh(binary, args, cwd):
    r = subprocess.run([binary] + args, cwd=cwd, capture_output=True, text=True,
                       env=dict(os.environ, OBJSLAM_CACHE=os.path.join(cwd, "cache")))
    if r.returncode != 0:
        sys.exit(f"fixture command failed: objslam {' '.join(args)}\n{r.stderr}")
    return r.stdout


def fixtures(binary, w):
    """Valid inputs of every kind, made by objslam itself, to edit."""
    f = {}
    f["defaults"] = sh(binary, ["config", "defaults"], w)
    sh(binary, ["world", "generate", "--seed", "3", "--out", "world.toml"], w)
    sh(binary, ["world", "export", "world.toml", "--out", "world.glb"], w)
    sh(binary, ["dataset", "--preset", "park", "--images", "6", "--seed", "2", "--out", "ds"], w)
    sh(binary, ["train", "--dataset", "ds", "--out", "model.json", "--pca-dims", "6", "--max-components", "3"], w)
    images = sorted(x for x in os.listdir(os.path.join(w, "ds", "images")) if x.endswith(".png"))
    f["image"] = os.path.join("ds", "images", images[0])
    rng = random.Random(3)
    rows = ["x,y,z"] + [
        ",".join(f"{rng.gauss(c, 1.0):.4f}" for _ in range(3)) for c in (0.0, 6.0) for _ in range(200)
    ]
    with open(os.path.join(w, "points.csv"), "w") as fh:
        fh.write("\n".join(rows) + "\n")
    sh(binary, ["gmm", "fit", "points.csv", "--out", "gmm.json", "--max-components", "4"], w)
    # Without camera frames: the robot-log cases replay with `nn`, which reads none.
    sh(binary, ["record", "park", "--duration", "15", "--format", "log", "--no-camera", "--out", "log"], w)
    sh(binary, ["record", "park", "--duration", "15", "--out", "rec"], w)
    return f


def read(w, name, binary=False):
    with open(os.path.join(w, name), "rb" if binary else "r") as fh:
        return fh.read()


def build_cases(binary, w, kinds):
    rng = random.Random(1)
    fx = fixtures(binary, w)
    defaults = fx["defaults"]
    cases = []

    # Scenarios: every numeric setting, then the combinations the settings cannot show.
    scenario_cmd = ["config", "check", "FILE"]
    cases += settings_cases("scenario", defaults, "probe/scenario.toml", scenario_cmd)
    base = defaults
    for label, old, new, field in [
        ("typo in [pipeline]", "gate_probability = 0.99", "gate_probabilty = 0.99", "gate_probabilty"),
        ("unknown method", 'method = "combined"', 'method = "bogus"', "bogus"),
        ("calibration mode typo", 'mode = "true"', 'mode = "ture"', "ture"),
        ("name with a path", 'name = "my_scenario"', 'name = "../../x"', "name"),
        ("gate probability 1", "gate_probability = 0.99", "gate_probability = 1.0", "gate_probability"),
        ("confirm_observations 0", "confirm_observations = 8", "confirm_observations = 0", "confirm_observations"),
        ("zero range noise in the filter", "range_sigma_m = 0.05", "range_sigma_m = 0.0", "range_sigma_m"),
        ("inverted band", "above_band_m = 2.7", "above_band_m = 1.0", "above_band_m"),
        ("missing world file", 'preset = "park"', 'file = "no_such_world.toml"', "no_such_world.toml"),
        ("missing calibration file", 'mode = "true"', 'mode = "no_such_calibration.json"', "no_such_calibration.json"),
        ("number as text", "confirm_observations = 8", 'confirm_observations = "8"', "confirm_observations"),
        ("appearance dims above pca dims", "appearance_dims = 4", "appearance_dims = 11", "appearance_dims"),
        ("min above max false landmarks", "# max_false_landmarks = 0", "max_false_landmarks = 0\nmin_false_landmarks = 3",
         "min_false_landmarks"),
        ("yawed laser", "mount_yaw_deg = 0.0", "mount_yaw_deg = 30.0", "mount_yaw_deg"),
    ]:
        if label == "missing world file":
            # A world file takes no generator parameters: the [world.params] table goes.
            lines, skip = [], False
            for l in base.replace(old, new, 1).splitlines():
                if l.startswith("["):
                    skip = l == "[world.params]"
                if not skip:
                    lines.append(l)
            text = "\n".join(lines) + "\n"
        else:
            assert old in base, old
            text = base.replace(old, new, 1)
        cases.append(Case("scenario", label, ["config", "check", "probe/scenario.toml"],
                          ["scenario.toml" if "missing" not in label else field, field],
                          {os.path.join(w, "probe/scenario.toml"): text}))
    for c in cases:
        c.files = {os.path.join(w, k) if not os.path.isabs(k) else k: v for k, v in c.files.items()}

    more = []
    # Simulator settings and generator parameters given as files of their own.
    sim_text = table_of(defaults, "sim")
    more += settings_cases("sim-config", sim_text, "probe/sim.toml",
                           ["record", "park", "--sim-config", "FILE", "--duration", "1", "--out", "probe/rec"])
    params_text = table_of(defaults, "world.params")
    more += settings_cases("params", params_text, "probe/params.toml", ["world", "generate", "--params", "FILE"])

    # World files: NaN and infinities in every numeric field (a world's coordinates may be
    # negative, so only non-finite values are certainly bad).
    world = read(w, "world.toml")
    for line, table, key, value in numeric_lines(world):
        bads = [math.nan, math.inf] if not isinstance(value, list) else [[math.nan] + value[1:]]
        if isinstance(value, int) or (isinstance(value, list) and isinstance(value[0], int)):
            bads = [-1] if not isinstance(value, list) else []
        for bad in bads:
            # A field of a sub-table (objects' pose) may be named by its table: `objects[3].pose`.
            field = (key, table.rsplit(".", 1)[-1])
            more.append(Case("world", f"{table}.{key} = {toml_literal(bad)}", ["world", "check", "probe/world.toml"],
                             ["world.toml", field], {"probe/world.toml": edited(world, line, key, bad)}))
    more += corrupt_file_cases("world", world, "probe/world.toml", ["world", "check", "probe/world.toml"])

    # glTF meshes named by a world.
    glb = read(w, "world.glb", binary=True)
    meshed = re.sub(r"(\[\[objects\]\]\n)", r'\1mesh = "mesh.glb"\n', world, count=1)
    for c in corrupt_file_cases("gltf", glb, "probe/mesh.glb", ["world", "check", "probe/meshed.toml"]):
        c.files["probe/meshed.toml"] = meshed
        c.names = ["mesh.glb"]
        more.append(c)
    doc = {"asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}], "nodes": [{"children": [0]}]}
    more.append(Case("gltf", "node graph with a cycle", ["world", "check", "probe/meshed.toml"], ["mesh.glb"],
                     {"probe/mesh.glb": gltf_json_glb(doc), "probe/meshed.toml": meshed}))
    deep = {"asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}],
            "nodes": [{"children": [i + 1]} for i in range(200_000)] + [{}]}
    more.append(Case("gltf", "200,000 nested nodes", ["world", "check", "probe/meshed.toml"], ["mesh.glb"],
                     {"probe/mesh.glb": gltf_json_glb(deep), "probe/meshed.toml": meshed}))
    # One triangle's accessors, each made wrong in turn.
    triangle = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 0, -1) + struct.pack("<3I", 0, 1, 2)
    for label, position, indices, names in [
        ("POSITION of VEC2", {"type": "VEC2"}, {}, ["mesh.glb", "POSITION (accessor 0) is VEC2"]),
        ("POSITION of unsigned bytes", {"componentType": 5121}, {}, ["mesh.glb", "POSITION (accessor 0)"]),
        ("a billion positions", {"count": 1_000_000_000}, {}, ["mesh.glb", "accessor 0"]),
        ("float indices", {}, {"componentType": 5126}, ["mesh.glb", "indices (accessor 1)"]),
        ("two indices", {}, {"count": 2}, ["mesh.glb", "whole triangles"]),
    ]:
        doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
               "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
               "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                              "min": [0, 0, -1], "max": [1, 0, 0], **position},
                             {"bufferView": 1, "componentType": 5125, "count": 3, "type": "SCALAR", **indices}],
               "bufferViews": [{"buffer": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 36, "byteLength": 12}],
               "buffers": [{"byteLength": len(triangle)}]}
        more.append(Case("gltf", label, ["world", "check", "probe/meshed.toml"], names,
                         {"probe/mesh.glb": gltf_json_glb(doc, triangle), "probe/meshed.toml": meshed}))
    for label, uri, names in [("buffer named %FF", "%FF.bin", ["mesh.glb", "%FF.bin"]),
                              ("buffer named %2Fdev%2Fzero", "%2Fdev%2Fzero", ["mesh.glb", "not a regular file"])]:
        doc = {"asset": {"version": "2.0"}, "buffers": [{"uri": uri, "byteLength": 1_000_000}]}
        more.append(Case("gltf", label, ["world", "check", "probe/meshed.toml"], names,
                         {"probe/mesh.glb": gltf_json_glb(doc), "probe/meshed.toml": meshed}))

    # Appearance models.
    model = json.loads(read(w, "model.json"))
    seg = ["segment", fx["image"], "--model", "probe/model.json", "--out", "probe/seg.png"]
    more += json_type_cases("model", model, "probe/model.json", seg, 40, rng)
    more += corrupt_file_cases("model", json.dumps(model), "probe/model.json", seg)
    for label, path, value, field in [
        ("format_version 2", ("format_version",), 2, "format_version"),
        ("object_weight 0", ("object_weight",), 0.0, "object_weight"),
        ("object_weight 1.5", ("object_weight",), 1.5, "object_weight"),
        ("threshold 2", ("threshold",), 2.0, "threshold"),
        ("patch_size 0", ("extractor", "config", "patch_size"), 0, "patch_size"),
        ("channel_gain of 3", ("extractor", "config", "channel_gain"), [1.0, 1.0, 1.0], "channel_gain"),
        ("Gabor sigma 1e6", ("extractor", "config", "bank", "filters", 0, "sigma_px"), 1e6, "sigma_px"),
        ("Gabor wavelength 0", ("extractor", "config", "bank", "filters", 0, "lambda_px"), 0.0, "lambda_px"),
        ("prior nu0 -1", ("object", "prior", "nu0"), -1.0, "nu0"),
        ("prior beta0 0", ("object", "prior", "beta0"), 0.0, "beta0"),
        ("no components", ("object", "components"), [], "components"),
    ]:
        more.append(Case("model", label, seg, ["model.json", field], {"probe/model.json": json.dumps(set_path(model, path, value))}))
    fewer_dims = json.loads(json.dumps(model))
    fewer_dims["extractor"]["pca"]["variances"] = fewer_dims["extractor"]["pca"]["variances"][:-1]
    more.append(Case("model", "PCA variances one short", seg, ["model.json", "variances"], {"probe/model.json": json.dumps(fewer_dims)}))

    # Calibration files named by a scenario.
    cal_scenario = defaults.replace('mode = "true"', 'mode = "cal.json"', 1)
    good_cal = {"phi": [[0, 0, 1], [-1, 0, 0], [0, -1, 0]], "delta": [-0.06, 0.0, 0.15]}
    for label, doc, field in [
        ("delta 1e300", dict(good_cal, delta=[1e300, 0, 0]), "delta"),
        ("phi not a rotation", dict(good_cal, phi=[[1, 0, 0], [0, 1, 0], [0, 0, 2]]), "phi"),
        ("phi of two rows", dict(good_cal, phi=[[1, 0, 0], [0, 1, 0]]), "phi"),
        ("no delta", {"phi": good_cal["phi"]}, "delta"),
        ("delta as text", dict(good_cal, delta="0 0 0"), "delta"),
        ("delta of null", dict(good_cal, delta=[None, 0, 0]), "delta"),
    ]:
        more.append(Case("calibration", label, ["config", "check", "probe/cal_scenario.toml"], ["cal.json", field],
                         {"probe/cal.json": json.dumps(doc), "probe/cal_scenario.toml": cal_scenario}))
    for c in corrupt_file_cases("calibration", json.dumps(good_cal), "probe/cal.json",
                                ["config", "check", "probe/cal_scenario.toml"]):
        c.files["probe/cal_scenario.toml"] = cal_scenario
        more.append(c)

    # Mixture models of `objslam gmm fit`, and CSV data.
    gmm = json.loads(read(w, "gmm.json"))
    gscore = ["gmm", "score", "probe/gmm.json", "points.csv"]
    more += json_type_cases("gmm-model", gmm, "probe/gmm.json", gscore, 25, rng)
    more += corrupt_file_cases("gmm-model", json.dumps(gmm), "probe/gmm.json", gscore)
    fit = ["gmm", "fit", "probe/data.csv", "--out", "probe/fit.json"]
    for label, text in [
        ("header only", "x,y,z\n"),
        ("a NaN cell", "x,y\n1,2\nnan,3\n4,5\n"),
        ("an inf cell", "x,y\n1,2\ninf,3\n4,5\n"),
        ("a text cell", "x,y\n1,2\nabc,3\n4,5\n"),
        ("a ragged row", "x,y\n1,2\n3\n4,5\n"),
        ("an empty cell", "x,y\n1,2\n,3\n4,5\n"),
        ("1e400", "x,y\n1,2\n1e400,3\n4,5\n"),
        ("1e200, whose square overflows", "x,y\n1,2\n1e200,3\n4,5\n"),
    ]:
        more.append(Case("csv", label, fit, ["data.csv"], {"probe/data.csv": text}))
    more += corrupt_file_cases("csv", read(w, "points.csv"), "probe/data.csv", fit)[2:]
    more.append(Case("csv", "wrong columns for the model", ["gmm", "score", "gmm.json", "probe/data.csv"],
                     ["data.csv", "columns"], {"probe/data.csv": "x,y\n1,2\n3,4\n"}))

    # Images.
    seg_img = ["segment", "probe/img.png", "--model", "model.json", "--out", "probe/seg.png"]
    for label, data in [
        ("empty", b""),
        ("not a PNG", b"GIF89a" + bytes(100)),
        ("truncated", read(w, fx["image"], binary=True)[:300]),
        ("header of 100000 x 100000", png(100_000, 100_000, rows=b"")),
        ("1 x 1 pixel", png(1, 1)),
        ("0 x 5 pixels", png(0, 5, rows=b"")),
    ]:
        more.append(Case("png", label, seg_img, ["img.png"], {"probe/img.png": data}))

    # Robot logs for `objslam replay`.
    log_files = {n: read(w, os.path.join("log", n)) for n in os.listdir(os.path.join(w, "log"))}
    def log_case(label, name, text, field):
        files = {f"probe/log/{n}": c for n, c in log_files.items()}
        if text is None:
            files.pop(f"probe/log/{name}")
        else:
            files[f"probe/log/{name}"] = text
        # Rows are named as file:line.
        names = [name] + ([field] if field and field != "line" else []) + ([f"{name}:"] if field == "line" else [])
        return Case("robot-log", label, ["replay", "probe/log", "--method", "nn", "--out", "probe/replay"],
                    names, files)
    manifest = log_files["manifest.toml"]
    odo = log_files["odometry.csv"].splitlines()
    odo_name = "odometry.csv"
    more.append(log_case("no manifest", "manifest.toml", None, None))
    more.append(log_case("format_version 9", "manifest.toml", manifest.replace("format_version = 1", "format_version = 9"), "format_version"))
    more.append(log_case("unknown manifest key", "manifest.toml", manifest + "\nspeed_of_light = 3\n", "speed_of_light"))
    for line, table, key, value in numeric_lines(manifest):
        if key == "format_version":
            continue
        for bad in [math.nan, math.inf] if isinstance(value, float) else []:
            more.append(log_case(f"manifest {table}.{key} = {toml_literal(bad)}", "manifest.toml",
                                 edited(manifest, line, key, bad), key))
    more.append(log_case("odometry back in time", odo_name, "\n".join([odo[0], odo[3], odo[2], odo[1]] + odo[4:]) + "\n", "line"))
    more.append(log_case("odometry NaN", odo_name, "\n".join(odo[:5] + [re.sub(r",[^,]*$", ",nan", odo[5])] + odo[6:]) + "\n", "line"))
    more.append(log_case("odometry short row", odo_name, "\n".join(odo[:5] + [odo[5].rsplit(",", 1)[0]] + odo[6:]) + "\n", "line"))
    more.append(log_case("odometry bad header", odo_name, "\n".join(["t,a,b,c"] + odo[1:]) + "\n", "header"))
    more.append(log_case("odometry empty", odo_name, "", None))
    more.append(log_case("odometry header alone", odo_name, odo[0] + "\n", None))
    more.append(log_case("odometry blank line", odo_name, "\n".join(odo[:4] + [""] + odo[5:]) + "\n", "line"))
    more.append(log_case("odometry not UTF-8", odo_name, ("\n".join(odo[:4]) + "\n").encode() + b"0.99,\xff\xfe,0,0\n", "line"))
    # Finite but impossible: would overflow the filter, or a file cut short.
    more.append(log_case("odometry step of 1e300 m", odo_name, "\n".join(odo[:5] + [re.sub(r"^([^,]*),[^,]*", r"\1,1e300", odo[5])] + odo[6:]) + "\n", "line"))
    more.append(log_case("odometry cut to half", odo_name, "\n".join(odo[:len(odo) // 2]) + "\n", None))
    more.append(log_case("manifest start_pose of 4", "manifest.toml",
                         re.sub(r"start_pose = \[([^\]]*)\]", r"start_pose = [\1, 0.0]", manifest), "start_pose"))
    if "scans.csv" in log_files:
        scans = log_files["scans.csv"].splitlines()
        cells = scans[3].split(",")
        cells[1] = "nan"
        more.append(log_case("scan NaN range", "scans.csv", "\n".join(scans[:3] + [",".join(cells)] + scans[4:]) + "\n", "line"))
        more.append(log_case("scan short row", "scans.csv", "\n".join(scans[:3] + [scans[3].rsplit(",", 5)[0]] + scans[4:]) + "\n", "line"))
        more.append(log_case("scans back in time", "scans.csv", "\n".join([scans[0], scans[2], scans[1]] + scans[3:]) + "\n", "line"))
        more.append(log_case("scans header alone", "scans.csv", scans[0] + "\n", None))
        more.append(log_case("scans without beams", "scans.csv", "\n".join(l.split(",")[0] for l in scans) + "\n", "line"))
    if "reference.csv" in log_files:
        ref = log_files["reference.csv"].splitlines()
        more.append(log_case("reference NaN", "reference.csv", "\n".join(ref[:3] + [re.sub(r"^([^,]*),[^,]*", r"\1,nan", ref[3])] + ref[4:]) + "\n", "line"))
        more.append(log_case("reference table, no reference.csv", "reference.csv", None, "reference"))
    more.append(log_case("pipeline.toml bad gate", "pipeline.toml", "gate_probability = 2.0\n", "gate_probability"))

    # Estimates given to `objslam score`.
    tum = read(w, os.path.join("rec", "ground_truth.tum")).splitlines()
    score = ["score", "--log", "rec", "--trajectory", "probe/est.tum", "--out", "probe/score"]
    for label, text in [
        ("NaN pose", "\n".join(tum[:3] + ["nan " + tum[3].split(" ", 1)[1]] + tum[4:]) + "\n"),
        ("times back", "\n".join([tum[2], tum[1], tum[0]] + tum[3:]) + "\n"),
        ("seven columns", "\n".join(" ".join(l.split()[:7]) for l in tum) + "\n"),
        ("zero quaternion", "\n".join(tum[:3] + [" ".join(tum[3].split()[:4] + ["0", "0", "0", "0"])] + tum[4:]) + "\n"),
        ("text", "hello world\n"),
        ("empty", ""),
    ]:
        more.append(Case("estimate", f"trajectory: {label}", score, ["est.tum"], {"probe/est.tum": text}))
    lm = ["score", "--log", "rec", "--trajectory", os.path.join("rec", "ground_truth.tum"), "--landmarks", "probe/lm.json", "--out", "probe/score"]
    for label, text, field in [
        ("landmarks not a list", '{"id": 1}', None),
        ("landmark without position", '[{"id": 1}]', "position"),
        ("landmark position of 1", '[{"id": 1, "position": [1.0]}]', "position"),
        ("landmark position text", '[{"id": 1, "position": "here"}]', "position"),
        ("duplicate landmark ids", '[{"id": 1, "position": [1, 2]}, {"id": 1, "position": [3, 4]}]', "id"),
    ]:
        more.append(Case("estimate", label, lm, ["lm.json"] + ([field] if field else []), {"probe/lm.json": text}))

    # Associations given by beams, and a record log whose camera index was cut.
    t0 = json.loads(read(w, os.path.join("rec", "laser.jsonl")).splitlines()[0])["t"]
    assoc = ["score", "--log", "rec", "--trajectory", os.path.join("rec", "ground_truth.tum"),
             "--associations", "probe/assoc.jsonl", "--out", "probe/score"]
    for label, line, field in [
        ("observations sharing beams",
         {"t": t0, "observations": [{"first_beam": 0, "last_beam": 5, "landmark": 1},
                                    {"first_beam": 3, "last_beam": 8, "landmark": 2}]}, "overlap"),
        ("beams reversed", {"t": t0, "observations": [{"first_beam": 8, "last_beam": 3, "landmark": 1}]}, "after the last"),
        ("fusion of landmarks never made", {"t": t0, "observations": [], "fusions": [{"kept": 1, "removed": 2}]},
         "fused before"),
    ]:
        more.append(Case("estimate", label, assoc, ["assoc.jsonl", field], {"probe/assoc.jsonl": json.dumps(line) + "\n"}))
    cut = {os.path.join("probe", "reccut", n): read(w, os.path.join("rec", n), binary=True)
           for n in os.listdir(os.path.join(w, "rec")) if os.path.isfile(os.path.join(w, "rec", n)) and n != "camera.jsonl"}
    cut["probe/reccut/camera.jsonl"] = "\n".join(read(w, os.path.join("rec", "camera.jsonl")).splitlines()[:2]) + "\n"
    more.append(Case("estimate", "camera index cut",
                     ["score", "--log", "probe/reccut", "--trajectory", os.path.join("rec", "ground_truth.tum"),
                      "--out", "probe/score"], ["camera.jsonl", "camera_frames"], cut))

    # Monte Carlo study directories.
    study = ["montecarlo", "laser_only", "--runs", "1", "--methods", "nn", "--jobs", "1", "--out", "probe/study"]
    more.append(Case("study", "study.json not JSON", study, ["study.json"], {"probe/study/study.json": "not json"}))
    more.append(Case("study", "study.json of another plan", study, ["study.json"],
                     {"probe/study/study.json": json.dumps({"scenario": "crowd", "base_seed": 9, "runs": 5, "methods": ["jcbb"], "vary": []})}))
    more.append(Case("study", "study.json not UTF-8", study, ["study.json"], {"probe/study/study.json": b"\xff\xfe\x00bad"}))

    # Command-line values.
    for args, flag in [
        (["montecarlo", "laser_only", "--runs", "1000000000", "--out", "probe/mc"], "runs"),
        (["montecarlo", "laser_only", "--vary", "sim.odometry.scale_sigma=0..1:100000000", "--out", "probe/mc"], "vary"),
        (["montecarlo", "laser_only", "--vary", "sim.odometry.scale_sigma=-1e308..1e308:3", "--out", "probe/mc"], "vary"),
        (["montecarlo", "laser_only", "--vary", "sim.nothing=0..1:3", "--methods", "nn", "--out", "probe/mc"], "sim.nothing"),
        (["montecarlo", "laser_only", "--methods", ",", "--out", "probe/mc"], "method"),
        (["montecarlo", "laser_only", "--shard", "5/2", "--out", "probe/mc"], "shard"),
        (["montecarlo", "laser_only", "--methods", "nn", "--vary", "sim.odometry.scale_sigma=0..0.1:2",
          "--vary", "sim.odometry.scale_sigma=0..0.2:2", "--out", "probe/mc"], "scale_sigma"),
        (["montecarlo", "laser_only", "--methods", "nn", "--vary", "pipeline.confirm_observations=1.5..2.5:2",
          "--out", "probe/mc"], "confirm_observations"),
        (["montecarlo", "laser_only", "--jobs", "0", "--out", "probe/mc"], "jobs"),
        (["calibrate", "calibration", "--poses", "1000000000", "--out", "probe/c.json"], "poses"),
        (["dataset", "--preset", "park", "--images", "1000000000", "--out", "probe/ds"], "images"),
        (["dataset", "--preset", "park", "--images", "0", "--out", "probe/ds"], "images"),
        (["dataset", "--preset", "park", "--patch-size", "0", "--images", "1", "--out", "probe/ds"], "patch"),
        (["record", "park", "--duration", "nan", "--out", "probe/r"], "duration"),
        (["train", "--dataset", "ds", "--out", "probe/m.json", "--pca-dims", "0"], "pca"),
        (["gmm", "fit", "points.csv", "--out", "probe/g.json", "--max-components", "0"], "max-components"),
        (["gmm", "fit", "points.csv", "--out", "probe/g.json", "--max-components", "100000000"], "max-components"),
        (["world", "generate", "--preset", "jungle"], "jungle"),
        (["run", "no_such_scenario"], "no_such_scenario"),
    ]:
        more.append(Case("arguments", " ".join(args[:4]), args, [flag]))

    # Output paths: something standing where the directory goes, an output that is an input.
    for args, names, files in [
        (["run", "laser_only", "--out", "probe/afile"], ["probe/afile", "is a file"], {"probe/afile": ""}),
        (["record", "park", "--duration", "1", "--out", "probe/afile/sub"], ["probe/afile", "is a file"],
         {"probe/afile": ""}),
        (["dataset", "--preset", "park", "--images", "1", "--out", "probe/afile"], ["probe/afile", "is a file"],
         {"probe/afile": ""}),
        (["montecarlo", "laser_only", "--runs", "1", "--methods", "nn", "--out", "probe/afile"],
         ["probe/afile", "is a file"], {"probe/afile": ""}),
        (["world", "export", "probe/w.toml", "--out", "probe/w.toml"], ["w.toml", "world file given"],
         {"probe/w.toml": world}),
        (["world", "plot", "probe/w.toml", "--out", "probe/w.svg"], ["w.svg", ".png"], {"probe/w.toml": world}),
        (["gmm", "fit", "probe/p.csv", "--out", "probe/p.csv"], ["p.csv", "data given"],
         {"probe/p.csv": read(w, "points.csv")}),
        (["score", "--log", "rec", "--trajectory", os.path.join("rec", "ground_truth.tum"), "--out", "rec"],
         ["rec", "log given"], {}),
    ]:
        more.append(Case("outputs", " ".join(args[:3]), args, names, files))

    # The unedited inputs, through the same commands: each must succeed.
    controls = [
        Case("scenario", "unedited", scenario_cmd[:2] + ["probe/scenario.toml"], [], {"probe/scenario.toml": defaults}),
        Case("sim-config", "unedited", ["record", "park", "--sim-config", "probe/sim.toml", "--duration", "1", "--out",
                                        "probe/rec"], [], {"probe/sim.toml": sim_text}),
        Case("params", "unedited", ["world", "generate", "--params", "probe/params.toml"], [],
             {"probe/params.toml": params_text}),
        Case("world", "unedited", ["world", "check", "probe/world.toml"], [], {"probe/world.toml": world}),
        Case("model", "unedited", seg, [], {"probe/model.json": json.dumps(model)}),
        Case("calibration", "unedited", ["config", "check", "probe/cal_scenario.toml"], [],
             {"probe/cal.json": json.dumps(good_cal), "probe/cal_scenario.toml": cal_scenario}),
        Case("gmm-model", "unedited", gscore, [], {"probe/gmm.json": json.dumps(gmm)}),
        Case("csv", "unedited", fit, [], {"probe/data.csv": read(w, "points.csv")}),
        Case("png", "unedited", seg_img, [], {"probe/img.png": read(w, fx["image"], binary=True)}),
        Case("robot-log", "unedited", ["replay", "probe/log", "--method", "nn", "--out", "probe/replay"], [],
             {f"probe/log/{n}": c for n, c in log_files.items()}),
        Case("estimate", "unedited", lm, [], {"probe/lm.json": '[{"id": 1, "position": [1.0, 2.0]}]'}),
        Case("study", "unedited", study, []),
    ]
    for c in more + controls:
        c.files = {os.path.join(w, k): v for k, v in c.files.items()}
    cases += more
    wanted = lambda c: not kinds or c.kind in kinds
    return [c for c in cases if wanted(c)], [c for c in controls if wanted(c)]


def gltf_json_glb(doc, bin_chunk=None):
    body = json.dumps(doc).encode()
    body += b" " * (-len(body) % 4)
    chunk = struct.pack("<II", len(body), 0x4E4F534A) + body
    if bin_chunk is not None:
        bin_chunk += b"\0" * (-len(bin_chunk) % 4)
        chunk += struct.pack("<II", len(bin_chunk), 0x004E4942) + bin_chunk
    return struct.pack("<III", 0x46546C67, 2, 12 + len(chunk)) + chunk


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", default="target/release/objslam")
    ap.add_argument("--work", default=None, help="working directory (default: a temporary one)")
    ap.add_argument("--kinds", default="", help="comma-separated input kinds to try (default: all)")
    ap.add_argument("--timeout", type=float, default=60.0)
    ap.add_argument("--max-rss-mb", type=int, default=4096)
    ap.add_argument("--json", default=None, help="write every case's outcome here")
    a = ap.parse_args()
    binary = os.path.abspath(a.bin)
    work = a.work or tempfile.mkdtemp(prefix="objslam-campaign-")
    os.makedirs(work, exist_ok=True)
    kinds = set(k for k in a.kinds.split(",") if k)
    cases, controls = build_cases(binary, work, kinds)
    for c in controls:
        shutil.rmtree(os.path.join(work, "probe"), ignore_errors=True)
        outcome, last, _ = run_case(binary, c, a.timeout, a.max_rss_mb, work)
        if outcome not in ("accepted", "warned"):
            sys.exit(f"the unedited {c.kind} input was not accepted ({outcome}): {last}")
        print(f"control {c.kind}: accepted", file=sys.stderr)
    results = []
    counts = {}
    for i, c in enumerate(cases):
        probe = os.path.join(work, "probe")
        shutil.rmtree(probe, ignore_errors=True)
        outcome, last, secs = run_case(binary, c, a.timeout, a.max_rss_mb, work)
        counts.setdefault(c.kind, {o: 0 for o in OUTCOMES})[outcome] += 1
        results.append({"kind": c.kind, "case": c.label, "outcome": outcome, "seconds": round(secs, 2),
                        "message": last[0] if last else ""})
        print(f"[{i + 1}/{len(cases)}] {c.kind}: {c.label}: {outcome}", file=sys.stderr)
    print("| input kind | tried | " + " | ".join(OUTCOMES) + " |")
    print("|---|---:|" + "---:|" * len(OUTCOMES))
    total = {o: 0 for o in OUTCOMES}
    for kind, row in counts.items():
        print(f"| {kind} | {sum(row.values())} | " + " | ".join(str(row[o]) for o in OUTCOMES) + " |")
        for o in OUTCOMES:
            total[o] += row[o]
    print(f"| all | {sum(total.values())} | " + " | ".join(str(total[o]) for o in OUTCOMES) + " |")
    bad = [r for r in results if r["outcome"] != "clean"]
    if bad:
        print("\nNot clean:")
        for r in bad:
            print(f"- {r['kind']}: {r['case']}: {r['outcome']}: {r['message']}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(results, fh, indent=1)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
