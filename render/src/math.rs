//! Vector and column-major 4x4 matrix helpers on plain arrays (the crate needs no linear
//! algebra library), among them the public `IDENTITY` and `rigid_inverse`.

/// Column-major 4x4 identity.
pub const IDENTITY: [[f32; 4]; 4] =
    [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]];

pub(crate) fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

pub(crate) fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub(crate) fn dot3(a: &[f32; 4], b: &[f32; 4]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub(crate) fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

pub(crate) fn normalised(a: [f32; 3]) -> Option<[f32; 3]> {
    let n = dot(a, a).sqrt();
    (n > 1e-9 && n.is_finite()).then(|| a.map(|v| v / n))
}

/// `m * [p, 1]` for a column-major affine `m`.
pub(crate) fn transform_point(m: &[[f32; 4]; 4], p: [f32; 3]) -> [f32; 3] {
    std::array::from_fn(|r| m[0][r] * p[0] + m[1][r] * p[1] + m[2][r] * p[2] + m[3][r])
}

/// Inverse of a rigid column-major transform: [R^T, -R^T t].
pub fn rigid_inverse(m: &[[f32; 4]; 4]) -> [[f32; 4]; 4] {
    let mut out = IDENTITY;
    for c in 0..3 {
        for r in 0..3 {
            out[c][r] = m[r][c];
        }
        out[3][c] = -dot3(&m[c], &m[3]);
    }
    out
}

/// Determinant of the upper-left 3x3 of a column-major 4x4 matrix.
pub(crate) fn determinant3(m: &[[f32; 4]; 4]) -> f32 {
    dot3(&m[0], &{
        let c = cross([m[1][0], m[1][1], m[1][2]], [m[2][0], m[2][1], m[2][2]]);
        [c[0], c[1], c[2], 0.0]
    })
}

pub(crate) fn mat_mul(a: &[[f32; 4]; 4], b: &[[f32; 4]; 4]) -> [[f32; 4]; 4] {
    std::array::from_fn(|c| std::array::from_fn(|r| (0..4).map(|k| a[k][r] * b[c][k]).sum()))
}

/// Columns of the inverse transpose of `m`'s upper 3x3 (the cofactor matrix, scaled; the
/// shader normalises), padded for std140.
pub(crate) fn normal_matrix(m: &[[f32; 4]; 4]) -> [[f32; 4]; 3] {
    let col = |c: usize| [m[c][0], m[c][1], m[c][2]];
    let (a, b, c) = (col(0), col(1), col(2));
    // For M = [a b c], inverse transpose = [b x c, c x a, a x b] / det.
    let det = dot(a, cross(b, c));
    let s = if det.abs() > 1e-20 { 1.0 / det } else { 1.0 };
    [cross(b, c), cross(c, a), cross(a, b)].map(|v| [v[0] * s, v[1] * s, v[2] * s, 0.0])
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Rotation by `yaw` about z, then translation.
    pub(crate) fn pose(yaw: f32, t: [f32; 3]) -> [[f32; 4]; 4] {
        let (s, c) = yaw.sin_cos();
        [[c, s, 0.0, 0.0], [-s, c, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [t[0], t[1], t[2], 1.0]]
    }

    #[test]
    fn rigid_inverse_undoes_the_transform() {
        let m = pose(0.7, [1.0, -2.0, 3.0]);
        let p = [0.3, 0.4, -0.5];
        let q = transform_point(&rigid_inverse(&m), transform_point(&m, p));
        assert!((0..3).all(|k| (p[k] - q[k]).abs() < 1e-5), "{q:?}");
        let i = mat_mul(&m, &rigid_inverse(&m));
        assert!((0..4).all(|c| (0..4).all(|r| (i[c][r] - IDENTITY[c][r]).abs() < 1e-6)));
    }

    #[test]
    fn normal_matrix_keeps_normals_perpendicular_under_scaling() {
        let mut m = IDENTITY;
        m[0][0] = 3.0; // stretch x
        let n = normal_matrix(&m);
        // A surface along x with normal (1, 1, 0)/sqrt2 becomes flatter: normal leans to y.
        let v = [1.0, 1.0, 0.0];
        let out: [f32; 3] = std::array::from_fn(|r| n[0][r] * v[0] + n[1][r] * v[1] + n[2][r] * v[2]);
        // Tangent (1, -1, 0) maps to (3, -1, 0); the normal must stay perpendicular to it.
        assert!((out[0] * 3.0 - out[1]).abs() < 1e-6, "{out:?}");
    }
}
