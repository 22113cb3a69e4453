//! Levenberg-Marquardt on a linear block-arrowhead problem, against the dense normal
//! equations' solution.

use super::*;

/// Per frame f: residuals `a_f + b t_i + c t_i^2 - y_fi` (frame offset a_f, shared b and c).
struct Lines {
    t: Vec<f64>,
    y: Vec<Vec<f64>>,
}

impl Lines {
    fn residuals(&self, x: &[f64]) -> Vec<(usize, f64, [f64; 3])> {
        let frames = self.y.len();
        let (b, c) = (x[frames], x[frames + 1]);
        let mut out = Vec::new();
        for (f, ys) in self.y.iter().enumerate() {
            for (t, y) in self.t.iter().zip(ys) {
                out.push((f, x[f] + b * t + c * t * t - y, [1.0, *t, t * t]));
            }
        }
        out
    }
}

impl ArrowProblem for Lines {
    fn dims(&self) -> (usize, usize, usize) {
        (self.y.len(), 1, 2)
    }
    fn cost(&self, x: &[f64]) -> Result<f64> {
        Ok(self.residuals(x).iter().map(|(_, r, _)| 0.5 * r * r).sum())
    }
    fn linearize(&self, x: &[f64], normal: &mut ArrowNormal) -> Result<f64> {
        normal.clear();
        let frames = self.y.len();
        for (f, r, j) in self.residuals(x) {
            normal.a[f] += j[0] * j[0];
            normal.b[2 * f] += j[0] * j[1];
            normal.b[2 * f + 1] += j[0] * j[2];
            normal.c[0] += j[1] * j[1];
            normal.c[1] += j[1] * j[2];
            normal.c[2] += j[2] * j[1];
            normal.c[3] += j[2] * j[2];
            normal.g[f] += j[0] * r;
            normal.g[frames] += j[1] * r;
            normal.g[frames + 1] += j[2] * r;
        }
        self.cost(x)
    }
    fn project(&self, _x: &mut [f64]) {}
    fn refresh(&mut self, _x: &[f64], _round: usize) -> Result<()> {
        Ok(())
    }
}

#[test]
fn linear_problem_reaches_the_least_squares_solution() {
    let t: Vec<f64> = (0..20).map(|i| i as f64 / 10.0).collect();
    let truth = ([0.5, -1.0, 2.0], 0.7, -0.3);
    let y = truth
        .0
        .iter()
        .enumerate()
        .map(|(f, a)| {
            t.iter()
                .enumerate()
                .map(|(i, t)| {
                    a + truth.1 * t + truth.2 * t * t + 0.01 * ((i * 7 + f * 3) % 5) as f64
                })
                .collect()
        })
        .collect();
    let mut problem = Lines { t, y };
    let mut x = vec![0.0; 5];
    let report = levenberg_marquardt(&mut problem, &mut x, &LmOptions::default()).unwrap();
    // Dense normal equations of the same problem.
    let rows = problem.residuals(&[0.0; 5]);
    let mut a = nalgebra::DMatrix::<f64>::zeros(5, 5);
    let mut g = nalgebra::DVector::<f64>::zeros(5);
    for (f, r, j) in rows {
        let full = [(f, j[0]), (3, j[1]), (4, j[2])];
        for &(p, u) in &full {
            g[p] += u * r;
            for &(q, v) in &full {
                a[(p, q)] += u * v;
            }
        }
    }
    let exact = a.cholesky().unwrap().solve(&(-g));
    for k in 0..5 {
        assert!(
            (x[k] - exact[k]).abs() < 1e-9,
            "parameter {k}: {} vs {}",
            x[k],
            exact[k]
        );
    }
    assert!(report.final_cost <= report.initial_cost);
    assert_ne!(report.status, LmStatus::NoDescent);
}
