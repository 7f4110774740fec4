//! Least squares with three unknowns, shared by the two fits the loop makes from data: the
//! spring-damper fallback ([`crate::serving::model::SpringDamper::fit`]) and the bench's friction
//! ([`crate::control::friction::fit`]). A module of its own so that neither fit imports the other's
//! module (friction used to reach into `model`, which imports `features`, which imports
//! `filters`, which imports `friction`: a cycle).

/// Why a fit gave no coefficients.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum FitError {
    /// Too few usable samples for the three unknowns.
    #[error("only {found} {what}: need at least {needed}")]
    TooFew {
        found: usize,
        needed: usize,
        what: &'static str,
    },
    /// The normal equations are singular (the data do not excite every unknown).
    #[error("singular fit ({0})")]
    Singular(&'static str),
    /// The fitted values fail the plausibility checks of what they describe.
    #[error("the fitted values are not plausible ({0})")]
    Implausible(String),
}

/// The normal equations `AᵀA x = Aᵀb`, accumulated one row at a time.
#[derive(Clone, Copy, Debug, Default)]
pub struct NormalEquations3 {
    ata: [[f64; 3]; 3],
    atb: [f64; 3],
    rows: usize,
}

impl NormalEquations3 {
    /// Adds the observation `row · x = y`.
    pub fn add(&mut self, row: [f64; 3], y: f64) {
        for r in 0..3 {
            for c in 0..3 {
                self.ata[r][c] += row[r] * row[c];
            }
            self.atb[r] += row[r] * y;
        }
        self.rows += 1;
    }

    /// Rows added so far.
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// The least-squares solution, `None` when singular or not finite.
    pub fn solve(&self) -> Option<[f64; 3]> {
        solve3(self.ata, self.atb)
    }
}

#[allow(clippy::needless_range_loop)] // index form mirrors the textbook elimination
fn solve3(mut a: [[f64; 3]; 3], mut b: [f64; 3]) -> Option<[f64; 3]> {
    // Column-scaled Gaussian elimination with partial pivoting.
    for col in 0..3 {
        let piv = (col..3).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[piv][col].abs() < 1e-300 {
            return None;
        }
        a.swap(col, piv);
        b.swap(col, piv);
        for r in col + 1..3 {
            let k = a[r][col] / a[col][col];
            for c in col..3 {
                a[r][c] -= k * a[col][c];
            }
            b[r] -= k * b[col];
        }
    }
    let mut x = [0.0; 3];
    for r in (0..3).rev() {
        let mut s = b[r];
        for c in r + 1..3 {
            s -= a[r][c] * x[c];
        }
        x[r] = s / a[r][r];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_an_exact_solution_and_refuses_a_singular_system() {
        let truth = [2.0, -3.0, 0.5];
        let mut n = NormalEquations3::default();
        for i in 0..20 {
            let t = i as f64 * 0.3;
            let row = [1.0, t, t * t];
            n.add(row, row.iter().zip(truth).map(|(a, b)| a * b).sum());
        }
        assert_eq!(n.rows(), 20);
        let x = n.solve().unwrap();
        for (a, b) in x.iter().zip(truth) {
            assert!((a - b).abs() < 1e-9, "{x:?}");
        }
        let mut s = NormalEquations3::default();
        for _ in 0..5 {
            s.add([1.0, 1.0, 0.0], 1.0);
        }
        assert_eq!(s.solve(), None);
    }
}
