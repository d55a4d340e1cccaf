//! A replay scored against its log's reference (ground truth or GPS) with memory that does
//! not grow with the log's length: the GPS's spikes are found in a first pass over the
//! reference that holds a few fixes at a time ([`GpsSpikeFinder`]), the samples are paired
//! with the estimate as the poses come ([`ReferencePairs`]), and the pairs wait on disk
//! until the end, when the alignment and the errors take passes over them ([`PairStore`]).

use std::collections::VecDeque;
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use robotlog::stream::Rows;
use robotlog::{ReferenceKind, ReferencePoint, ReferenceSample};
use serde::Serialize;

use super::{ReplayError, ThinnedPath};

/// Highest speed a GPS fix may imply from both its neighbours before it is taken for a
/// spike (m/s): far above what a vehicle in a park drives (Victoria Park's car: 6.6 m/s
/// at most), far below the spikes' hundreds of m/s.
pub const GPS_SPIKE_SPEED_MPS: f64 = 15.0;

/// Most consecutive GPS fixes one spike may hold.
pub const GPS_SPIKE_MAX_FIXES: usize = 3;

/// The estimate against the log's reference.
#[derive(Debug, Clone, Serialize)]
pub struct ReferenceScore {
    pub kind: ReferenceKind,
    pub point: ReferencePoint,
    pub samples: usize,
    /// GPS fixes dropped as spikes (see [`gps_spikes`]), decided from the GPS alone.
    pub spikes_removed: usize,
    /// Samples inside the estimate's time span, scored.
    pub samples_scored: usize,
    /// "rigid 2-D" (GPS) or "none" (ground truth in the estimate's frame).
    pub alignment: String,
    pub alignment_rotation_rad: f64,
    pub alignment_translation_m: [f64; 2],
    pub ate_rmse_m: f64,
    pub ate_max_m: f64,
    /// Ground truth only: the ATE after a rigid 2-D fit, as GPS is scored (null for GPS, and
    /// with fewer than [`MIN_ALIGNED_SAMPLES`]). Far below `ate_rmse_m`, it says the ground
    /// truth is in another frame (UTM, a map's), which the summary names.
    pub ate_rmse_if_aligned_m: Option<f64>,
}

impl ReferenceScore {
    /// Whether ground truth scored as given is in another frame than the estimate's: a rigid
    /// fit takes its ATE to under a tenth, from more than 10 m. In one frame a fit only
    /// removes what the start pose's error turned, which cannot take 10 m of error to 1.
    pub fn in_another_frame(&self) -> bool {
        self.ate_rmse_if_aligned_m.is_some_and(|aligned| self.ate_rmse_m > 10.0 && self.ate_rmse_m > 10.0 * aligned)
    }
}

/// Indices of GPS fixes that are spikes, decided from the GPS alone, never from the
/// estimate being scored, for a vehicle that stays under `max_speed` (m/s). A spike is a
/// run of 1 to [`GPS_SPIKE_MAX_FIXES`] fixes, each reached from the last fix kept before
/// the run and left to the fix after it at more than `max_speed`, while those two agree
/// with each other. Then, at either end of the log, where one neighbour is missing, a
/// single fix is a spike when the two kept fixes on its one side agree (more fixes there
/// may as well be where the GPS went on to).
pub fn gps_spikes(samples: &[ReferenceSample], max_speed: f64) -> Vec<usize> {
    let mut finder = GpsSpikeFinder::new(max_speed);
    for s in samples {
        finder.push(*s);
    }
    finder.finish()
}

/// A GPS fix and its index in the log.
type Fix = (usize, ReferenceSample);

/// [`gps_spikes`] a fix at a time, holding at most [`GPS_SPIKE_MAX_FIXES`] + 2 fixes and
/// the first and last three kept (a run of fixes is decided once the fix after its longest
/// possible spike has come).
pub struct GpsSpikeFinder {
    max_speed: f64,
    /// Fixes pushed so far.
    count: usize,
    /// The last fix kept inside the log, against which the next ones are judged.
    before: Option<Fix>,
    /// Fixes after `before` not yet decided.
    pending: VecDeque<Fix>,
    spikes: Vec<usize>,
    kept: usize,
    first_kept: Vec<Fix>,
    last_kept: VecDeque<Fix>,
}

impl GpsSpikeFinder {
    pub fn new(max_speed: f64) -> Self {
        GpsSpikeFinder {
            max_speed,
            count: 0,
            before: None,
            pending: VecDeque::new(),
            spikes: Vec::new(),
            kept: 0,
            first_kept: Vec::new(),
            last_kept: VecDeque::new(),
        }
    }

    /// The next fix in time order.
    pub fn push(&mut self, fix: ReferenceSample) {
        let k = self.count;
        self.count += 1;
        if self.before.is_none() {
            // The first fix is judged only at the end, against the two kept after it.
            self.keep((k, fix));
            return;
        }
        self.pending.push_back((k, fix));
        while self.pending.len() > GPS_SPIKE_MAX_FIXES {
            self.decide_first_pending();
        }
    }

    /// The spikes' indices, in order.
    pub fn finish(mut self) -> Vec<usize> {
        // The last fix is never inside a spike run: it has no fix after it.
        while self.pending.len() >= 2 {
            self.decide_first_pending();
        }
        if let Some(last) = self.pending.pop_front() {
            self.keep(last);
        }
        if self.kept >= 3 {
            let n = self.count;
            let [a0, a1, a2] = [0, 1, 2].map(|k| self.first_kept[k]);
            let [b0, b1, b2] = [2, 1, 0].map(|k| self.last_kept[k]);
            let at_end = |(end, a, b): (Fix, Fix, Fix)| {
                (end.0 == 0 || end.0 == n - 1)
                    && self.speed(&end.1, &a.1) > self.max_speed
                    && self.speed(&end.1, &b.1) > self.max_speed
                    && self.speed(&a.1, &b.1) <= self.max_speed
            };
            let (first, last) = (at_end((a0, a1, a2)), at_end((b0, b1, b2)));
            // Neither end is ever inside a run: the first is `before`, the last has no fix after it.
            if first {
                self.spikes.insert(0, a0.0);
            }
            if last {
                self.spikes.push(b0.0);
            }
        }
        self.spikes
    }

    fn speed(&self, a: &ReferenceSample, b: &ReferenceSample) -> f64 {
        (b.x - a.x).hypot(b.y - a.y) / (b.t - a.t).abs().max(1e-3)
    }

    /// Decides the first pending fix and, where it starts a spike, the rest of its run:
    /// every run length whose following fix has come is tried, shortest first.
    fn decide_first_pending(&mut self) {
        let before = self.before.expect("the first fix is kept").1;
        let max = self.max_speed;
        let run = (1..=GPS_SPIKE_MAX_FIXES).take_while(|&len| len < self.pending.len()).find(|&len| {
            let after = self.pending[len].1;
            self.pending.iter().take(len).all(|(_, s)| self.speed(s, &before) > max && self.speed(s, &after) > max)
                && self.speed(&before, &after) <= max
        });
        match run {
            Some(len) => {
                for _ in 0..len {
                    let (k, _) = self.pending.pop_front().expect("len < pending");
                    self.spikes.push(k);
                }
            }
            None => {
                let fix = self.pending.pop_front().expect("two pending");
                self.keep(fix);
            }
        }
    }

    fn keep(&mut self, fix: Fix) {
        self.before = Some(fix);
        self.kept += 1;
        if self.first_kept.len() < 3 {
            self.first_kept.push(fix);
        }
        self.last_kept.push_back(fix);
        if self.last_kept.len() > 3 {
            self.last_kept.pop_front();
        }
    }
}

/// The rotation and translation that best map `from` onto `to` (least squares, 2-D, no
/// scale): `to ≈ R(theta) from + t`.
pub fn rigid_alignment(from: &[[f64; 2]], to: &[[f64; 2]]) -> (f64, [f64; 2]) {
    let mut pairs = PairStore::in_memory();
    for (f, t) in from.iter().zip(to) {
        pairs.push(*f, *t).expect("in memory");
    }
    pairs.rigid_alignment().expect("in memory")
}

/// The (estimate, reference) pairs scored, in a file (removed when the store is dropped)
/// or, for a replay without an output directory, in memory.
pub(super) struct PairStore {
    len: usize,
    place: PairPlace,
}

enum PairPlace {
    Memory(Vec<[f64; 4]>),
    File { file: PathBuf, writer: BufWriter<File> },
}

impl PairStore {
    pub(super) fn in_memory() -> Self {
        PairStore { len: 0, place: PairPlace::Memory(Vec::new()) }
    }

    /// A store in `file`, made anew.
    pub(super) fn on_disk(file: &Path) -> Result<Self, ReplayError> {
        let writer = BufWriter::new(File::create(file).map_err(io(file))?);
        Ok(PairStore { len: 0, place: PairPlace::File { file: file.to_path_buf(), writer } })
    }

    fn len(&self) -> usize {
        self.len
    }

    fn push(&mut self, estimate: [f64; 2], reference: [f64; 2]) -> Result<(), ReplayError> {
        let pair = [estimate[0], estimate[1], reference[0], reference[1]];
        match &mut self.place {
            PairPlace::Memory(v) => v.push(pair),
            PairPlace::File { file, writer } => {
                for v in pair {
                    writer.write_all(&v.to_le_bytes()).map_err(io(file))?;
                }
            }
        }
        self.len += 1;
        Ok(())
    }

    /// Calls `f` with every pair, from the first.
    fn pass(&mut self, mut f: impl FnMut([f64; 2], [f64; 2])) -> Result<(), ReplayError> {
        match &mut self.place {
            PairPlace::Memory(v) => v.iter().for_each(|p| f([p[0], p[1]], [p[2], p[3]])),
            PairPlace::File { file, writer } => {
                writer.flush().map_err(io(file))?;
                let mut reader = BufReader::new(File::open(&*file).map_err(io(file))?);
                let mut bytes = [0u8; 32];
                for _ in 0..self.len {
                    reader.read_exact(&mut bytes).map_err(io(file))?;
                    let v: [f64; 4] = std::array::from_fn(|k| {
                        f64::from_le_bytes(bytes[8 * k..8 * k + 8].try_into().expect("8 bytes"))
                    });
                    f([v[0], v[1]], [v[2], v[3]]);
                }
            }
        }
        Ok(())
    }

    /// [`rigid_alignment`] of the estimates onto the references, in two passes.
    fn rigid_alignment(&mut self) -> Result<(f64, [f64; 2]), ReplayError> {
        let n = self.len.max(1) as f64;
        let (mut sf, mut st) = ([0.0, 0.0], [0.0, 0.0]);
        self.pass(|f, t| {
            sf = [sf[0] + f[0], sf[1] + f[1]];
            st = [st[0] + t[0], st[1] + t[1]];
        })?;
        let (mf, mt) = ([sf[0] / n, sf[1] / n], [st[0] / n, st[1] / n]);
        let (mut sxx, mut sxy) = (0.0, 0.0);
        self.pass(|f, t| {
            let (fx, fy, tx, ty) = (f[0] - mf[0], f[1] - mf[1], t[0] - mt[0], t[1] - mt[1]);
            sxx += fx * tx + fy * ty;
            sxy += fx * ty - fy * tx;
        })?;
        let theta = sxy.atan2(sxx);
        let (s, c) = theta.sin_cos();
        Ok((theta, [mt[0] - (c * mf[0] - s * mf[1]), mt[1] - (s * mf[0] + c * mf[1])]))
    }
}

impl Drop for PairStore {
    fn drop(&mut self) {
        if let PairPlace::File { file, .. } = &self.place {
            let _ = std::fs::remove_file(file);
        }
    }
}

fn io(file: &Path) -> impl FnOnce(std::io::Error) -> ReplayError + '_ {
    move |source| ReplayError::Io { file: file.to_path_buf(), source }
}

/// The reference samples scored (spikes left out) paired, as the poses come, with the
/// estimate at their times: linear between the last pose before and the first at or after.
/// The samples are read as the poses reach them; each is also kept, thinned, for the map
/// picture, and the spikes' places as they are.
pub(super) struct ReferencePairs {
    samples: Rows<ReferenceSample>,
    /// Index of the next sample read, and of the next spike among `spikes`.
    index: usize,
    spikes: Vec<usize>,
    next_spike: usize,
    /// The next sample scored, read and not yet paired.
    pending: Option<ReferenceSample>,
    last_pose: Option<(f64, [f64; 2])>,
    pairs: PairStore,
    drawn: ThinnedPath,
    dropped: Vec<[f64; 2]>,
}

/// What is left of the reference when the poses have ended.
pub(super) struct PairedReference {
    pub pairs: PairStore,
    /// Every sample scored or not, spikes apart, thinned for the map picture.
    pub drawn: Vec<[f64; 2]>,
    /// The spikes' places.
    pub dropped: Vec<[f64; 2]>,
}

impl ReferencePairs {
    /// `samples` in time order; `spikes` (their indices, in order) are left out.
    pub(super) fn new(samples: Rows<ReferenceSample>, spikes: Vec<usize>, pairs: PairStore) -> Self {
        ReferencePairs {
            samples,
            index: 0,
            spikes,
            next_spike: 0,
            pending: None,
            last_pose: None,
            pairs,
            drawn: ThinnedPath::default(),
            dropped: Vec::new(),
        }
    }

    /// Reads up to the next sample scored, unless one is waiting; false when none is left.
    fn fill(&mut self) -> Result<bool, ReplayError> {
        while self.pending.is_none() {
            let Some(sample) = self.samples.next() else { return Ok(false) };
            let sample = sample?;
            let k = self.index;
            self.index += 1;
            if self.spikes.get(self.next_spike) == Some(&k) {
                self.next_spike += 1;
                self.dropped.push([sample.x, sample.y]);
            } else {
                self.drawn.push([sample.x, sample.y]);
                self.pending = Some(sample);
            }
        }
        Ok(true)
    }

    /// The pose at `t` (the estimate's poses come in time order).
    pub(super) fn on_pose(&mut self, t: f64, p: [f64; 2]) -> Result<(), ReplayError> {
        while self.fill()? {
            let s = self.pending.expect("filled");
            if s.t > t {
                break;
            }
            match self.last_pose {
                // Before the first pose, only a sample at its very time is scored.
                None => {
                    if s.t == t {
                        self.pairs.push(p, [s.x, s.y])?;
                    }
                }
                Some((t0, p0)) => {
                    let a = if t > t0 { (s.t - t0) / (t - t0) } else { 1.0 };
                    self.pairs.push([p0[0] + a * (p[0] - p0[0]), p0[1] + a * (p[1] - p0[1])], [s.x, s.y])?;
                }
            }
            self.pending = None;
        }
        self.last_pose = Some((t, p));
        Ok(())
    }

    /// The pairs, with the samples after the last pose read for the picture.
    pub(super) fn finish(mut self) -> Result<PairedReference, ReplayError> {
        while self.fill()? {
            self.pending = None;
        }
        Ok(PairedReference { pairs: self.pairs, drawn: self.drawn.points(), dropped: self.dropped })
    }
}

/// The estimate against the reference from the `pairs` of the samples scored, aligned by
/// a rigid 2-D fit for GPS, as it is for ground truth. Three passes over the pairs for GPS
/// (the means, the cross terms, the errors), one for ground truth.
pub(super) fn score_reference(
    kind: ReferenceKind,
    point: ReferencePoint,
    samples: usize,
    spikes: usize,
    pairs: &mut PairStore,
) -> Result<ReferenceScore, ReplayError> {
    let n = pairs.len();
    let alignment = match kind {
        ReferenceKind::Gps => "rigid 2-D".to_string(),
        ReferenceKind::GroundTruth => "none".to_string(),
    };
    let score = |theta: f64, t: [f64; 2], ate_rmse_m: f64, ate_max_m: f64| ReferenceScore {
        kind,
        point,
        samples,
        spikes_removed: spikes,
        samples_scored: n,
        alignment: alignment.clone(),
        alignment_rotation_rad: theta,
        alignment_translation_m: t,
        ate_rmse_m,
        ate_max_m,
        ate_rmse_if_aligned_m: None,
    };
    // Nothing scored, or too few for a rigid fit to leave an error to measure: undefined,
    // written as null, never a perfect score.
    let fewest = match kind {
        ReferenceKind::Gps => MIN_ALIGNED_SAMPLES,
        ReferenceKind::GroundTruth => 1,
    };
    if n < fewest {
        return Ok(score(f64::NAN, [f64::NAN; 2], f64::NAN, f64::NAN));
    }
    let (theta, t) = match kind {
        ReferenceKind::Gps => pairs.rigid_alignment()?,
        ReferenceKind::GroundTruth => (0.0, [0.0, 0.0]),
    };
    let (rmse, max) = errors(pairs, theta, t)?;
    let mut scored = score(theta, t, rmse, max);
    if kind == ReferenceKind::GroundTruth && n >= MIN_ALIGNED_SAMPLES {
        let (theta, t) = pairs.rigid_alignment()?;
        scored.ate_rmse_if_aligned_m = Some(errors(pairs, theta, t)?.0);
    }
    Ok(scored)
}

/// The RMS and largest distance between the reference and the estimate moved by `theta`
/// and `t`, over `pairs`.
fn errors(pairs: &mut PairStore, theta: f64, t: [f64; 2]) -> Result<(f64, f64), ReplayError> {
    let (s, c) = theta.sin_cos();
    let (mut squares, mut max, mut n) = (0.0, 0.0f64, 0usize);
    pairs.pass(|e, g| {
        let error = (c * e[0] - s * e[1] + t[0] - g[0]).hypot(s * e[0] + c * e[1] + t[1] - g[1]);
        squares += error * error;
        max = max.max(error);
        n += 1;
    })?;
    Ok(((squares / n as f64).sqrt(), max))
}

/// Whether `scored` of the `kept` reference samples (spikes aside) are fewer than a tenth:
/// the reference of a longer session than the log, or one on another clock or in another
/// unit (ms), whose few samples there make the ATE of a moment. The summary says so; the
/// ATE stands (a GPS log begun long before the drive is sound), with its sample count.
pub fn too_little_within(scored: usize, kept: usize) -> bool {
    10 * scored < kept
}

/// Fewest GPS samples scored for an ATE after a rigid fit, which takes three degrees of
/// freedom from their 2n coordinates: one sample fits exactly whatever the estimate, two
/// leave only their distance apart; from three, at least as many are left as the fit took.
pub const MIN_ALIGNED_SAMPLES: usize = 3;

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn rigid_alignment_recovers_a_rotation_and_translation() {
        let from: Vec<[f64; 2]> = (0..20).map(|k| [k as f64, (k as f64 * 0.3).sin() * 4.0]).collect();
        let (s, c) = 0.7f64.sin_cos();
        let to: Vec<[f64; 2]> = from.iter().map(|p| [c * p[0] - s * p[1] + 5.0, s * p[0] + c * p[1] - 2.0]).collect();
        let (theta, t) = rigid_alignment(&from, &to);
        assert!((theta - 0.7).abs() < 1e-12 && (t[0] - 5.0).abs() < 1e-9 && (t[1] + 2.0).abs() < 1e-9);
    }

    #[test]
    fn gps_spikes_are_found_from_the_gps_alone() {
        let mut samples: Vec<ReferenceSample> =
            (0..10).map(|k| ReferenceSample { t: k as f64, x: 3.0 * k as f64, y: 0.0, theta: None }).collect();
        samples[4].y = 137.0;
        assert_eq!(gps_spikes(&samples, GPS_SPIKE_SPEED_MPS), vec![4]);
        // A jump that stays (a re-acquired fix in a new place) is not a spike.
        for s in &mut samples[7..] {
            s.x += 100.0;
        }
        assert_eq!(gps_spikes(&samples, GPS_SPIKE_SPEED_MPS), vec![4]);
        // Two and three fixes in a row, and one at either end.
        let mut samples: Vec<ReferenceSample> =
            (0..30).map(|k| ReferenceSample { t: k as f64, x: 3.0 * k as f64, y: 0.0, theta: None }).collect();
        for k in [0, 8, 9, 20, 21, 22, 29] {
            samples[k].y = 90.0 + k as f64;
        }
        assert_eq!(gps_spikes(&samples, GPS_SPIKE_SPEED_MPS), vec![0, 8, 9, 20, 21, 22, 29]);
        // Two at an end may be where the GPS went on to: not dropped.
        samples[28].y = 118.0;
        assert_eq!(gps_spikes(&samples, GPS_SPIKE_SPEED_MPS), vec![0, 8, 9, 20, 21, 22]);
        samples[28].y = 0.0;
        // Four in a row, off from both neighbours, are not a spike but a place the GPS
        // stayed; three there would be.
        for s in &mut samples[12..16] {
            s.y = 150.0;
        }
        assert_eq!(gps_spikes(&samples, GPS_SPIKE_SPEED_MPS), vec![0, 8, 9, 20, 21, 22, 29]);
        samples[15].y = 0.0;
        assert_eq!(gps_spikes(&samples, GPS_SPIKE_SPEED_MPS), vec![0, 8, 9, 12, 13, 14, 20, 21, 22, 29]);
        // A spike next to the start, and real fixes between two spikes at one false place,
        // are judged against kept fixes: the real ones stay.
        let mut samples: Vec<ReferenceSample> =
            (0..12).map(|k| ReferenceSample { t: k as f64, x: 3.0 * k as f64, y: 0.0, theta: None }).collect();
        for k in [1, 2, 6, 8] {
            samples[k].y = 200.0;
        }
        assert_eq!(gps_spikes(&samples, GPS_SPIKE_SPEED_MPS), vec![1, 2, 6, 8]);
    }

    /// The estimate paired with each reference sample as the poses come: interpolated
    /// between the poses around it, at the first pose only at its very time, never after
    /// the last pose.
    #[test]
    fn reference_samples_pair_with_the_estimate_interpolated_inside_it_only() {
        let samples: Vec<ReferenceSample> =
            [0.5, 1.0, 1.5, 2.5].iter().map(|&t| ReferenceSample { t, x: 10.0 * t, y: 0.0, theta: None }).collect();
        let paired = |spikes: Vec<usize>, poses: &[(f64, [f64; 2])]| {
            let rows: Rows<ReferenceSample> = Box::new(samples.clone().into_iter().map(Ok));
            let mut pairs = ReferencePairs::new(rows, spikes, PairStore::in_memory());
            for (t, p) in poses {
                pairs.on_pose(*t, *p).unwrap();
            }
            let mut done = pairs.finish().unwrap();
            let mut out = Vec::new();
            done.pairs.pass(|e, g| out.push((e, g))).unwrap();
            (out, done.drawn, done.dropped)
        };
        let (pairs, drawn, dropped) = paired(vec![], &[(1.0, [0.0, 0.0]), (2.0, [2.0, 4.0])]);
        assert_eq!(pairs, vec![([0.0, 0.0], [10.0, 0.0]), ([1.0, 2.0], [15.0, 0.0])]);
        assert_eq!(drawn.len(), 4, "the samples after the last pose are drawn, not scored");
        assert!(dropped.is_empty());
        // Two poses at one time: the first of them ends the interval; a sample before the
        // first pose is dropped.
        let (twice, ..) = paired(vec![], &[(1.0, [0.0, 0.0]), (1.5, [1.0, 0.0]), (1.5, [9.0, 9.0])]);
        assert_eq!(twice, vec![([0.0, 0.0], [10.0, 0.0]), ([1.0, 0.0], [15.0, 0.0])]);
        let (skipping, drawn, dropped) = paired(vec![1], &[(1.0, [0.0, 0.0]), (2.0, [2.0, 4.0])]);
        assert_eq!(skipping, vec![([1.0, 2.0], [15.0, 0.0])], "a spike is not scored");
        assert_eq!((drawn.len(), dropped), (3, vec![[10.0, 0.0]]), "a spike is drawn as such");
    }

    /// The rule of [`gps_spikes`] over the whole slice at once, as it was written before
    /// the fixes came one at a time: the oracle for [`GpsSpikeFinder`].
    fn gps_spikes_whole(samples: &[ReferenceSample], max_speed: f64) -> Vec<usize> {
        let speed = |a: usize, b: usize| {
            let (a, b) = (&samples[a], &samples[b]);
            (b.x - a.x).hypot(b.y - a.y) / (b.t - a.t).abs().max(1e-3)
        };
        let n = samples.len();
        let mut spike = vec![false; n];
        let mut before = 0;
        let mut i = 1;
        while i + 1 < n {
            let found = (1..=GPS_SPIKE_MAX_FIXES).map(|len| i + len - 1).take_while(|&j| j + 1 < n).find(|&j| {
                let after = j + 1;
                (i..=j).all(|k| speed(k, before) > max_speed && speed(k, after) > max_speed)
                    && speed(before, after) <= max_speed
            });
            match found {
                Some(j) => {
                    spike[i..=j].iter_mut().for_each(|s| *s = true);
                    i = j + 1;
                }
                None => {
                    before = i;
                    i += 1;
                }
            }
        }
        let kept: Vec<usize> = (0..n).filter(|&k| !spike[k]).collect();
        if kept.len() >= 3 {
            for (end, a, b) in
                [(kept[0], kept[1], kept[2]), (kept[kept.len() - 1], kept[kept.len() - 2], kept[kept.len() - 3])]
            {
                if (end == 0 || end == n - 1)
                    && speed(end, a) > max_speed
                    && speed(end, b) > max_speed
                    && speed(a, b) <= max_speed
                {
                    spike[end] = true;
                }
            }
        }
        (0..n).filter(|&k| spike[k]).collect()
    }

    proptest! {
        /// Fixes taken one at a time find the spikes the whole track does: tracks of a car
        /// at 3 m/s with fixes thrown off, alone and in runs, anywhere, ends included.
        #[test]
        fn spikes_found_a_fix_at_a_time_are_those_of_the_whole_track(
            n in 0usize..40,
            off in proptest::collection::vec((0usize..40, 1usize..5, 20.0f64..500.0), 0..6),
        ) {
            let mut samples: Vec<ReferenceSample> =
                (0..n).map(|k| ReferenceSample { t: 0.2 * k as f64, x: 0.6 * k as f64, y: 0.0, theta: None }).collect();
            for (start, len, dy) in off {
                for s in samples.iter_mut().skip(start).take(len) {
                    s.y += dy;
                }
            }
            prop_assert_eq!(gps_spikes(&samples, GPS_SPIKE_SPEED_MPS), gps_spikes_whole(&samples, GPS_SPIKE_SPEED_MPS));
        }
    }

    /// Pairs kept on disk score bit for bit as pairs kept in memory, and their file is
    /// gone when the store is.
    #[test]
    fn pairs_on_disk_score_as_pairs_in_memory_and_leave_no_file() {
        let dir = std::env::temp_dir().join(format!("objslam-pairs-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("pairs");
        let mut disk = PairStore::on_disk(&file).unwrap();
        let mut memory = PairStore::in_memory();
        for k in 0..1000 {
            let e = [k as f64 * 0.37 + 300_000.0, (k as f64 * 0.01).sin() * 50.0 + 6_200_000.0];
            let g = [e[0] * 0.999 + 12.5 + (k % 7) as f64 * 0.1, e[1] + 3.0 - (k % 5) as f64 * 0.2];
            disk.push(e, g).unwrap();
            memory.push(e, g).unwrap();
        }
        for kind in [ReferenceKind::Gps, ReferenceKind::GroundTruth] {
            let a = score_reference(kind, ReferencePoint::Sensor, 1000, 0, &mut disk).unwrap();
            let b = score_reference(kind, ReferencePoint::Sensor, 1000, 0, &mut memory).unwrap();
            assert_eq!(serde_json::to_string(&a).unwrap(), serde_json::to_string(&b).unwrap());
            assert!(a.ate_rmse_m > 0.0 && a.ate_max_m >= a.ate_rmse_m, "{a:?}");
        }
        assert!(file.is_file());
        drop(disk);
        assert!(!file.exists(), "the store removes its file");
        std::fs::remove_dir_all(&dir).ok();
    }
}
