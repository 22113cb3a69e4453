use super::rigid_held_out::rigid_held_out;
use crate::rigid::rigid_motions;

/// Two sets of 5 neighbours: the first rigidly moved but for one outlier, the second with
/// two neighbours not chosen.
fn sets() -> (Vec<[f64; 3]>, Vec<[f64; 3]>, Vec<f64>) {
    let a: Vec<[f64; 3]> = (0..10)
        .map(|i| {
            let f = i as f64;
            [f.sin() * 3.0, (0.7 * f).cos() * 2.0, 0.3 * f]
        })
        .collect();
    let mut b: Vec<[f64; 3]> = a
        .iter()
        .map(|p| [p[1] + 1.0, -p[0] + 0.5, p[2] - 2.0])
        .collect();
    b[3] = [b[3][0] + 0.4, b[3][1], b[3][2] - 0.3];
    let w = vec![1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.0, 1.0, 1.0, 0.0];
    (a, b, w)
}

fn miss(fit: &([f64; 9], [f64; 3]), p: [f64; 3], q: [f64; 3]) -> f64 {
    let (r, t) = fit;
    (0..3)
        .map(|i| r[3 * i] * p[0] + r[3 * i + 1] * p[1] + r[3 * i + 2] * p[2] + t[i] - q[i])
        .map(|d| d * d)
        .sum::<f64>()
        .sqrt()
}

#[test]
fn each_fit_is_the_fit_without_the_neighbour_to_the_bit() {
    let (a, b, w) = sets();
    let fits = rigid_held_out(&a, &b, &w, 5, 3.0);
    assert_eq!(fits.len(), 10);
    for m in 0..2 {
        for j in 0..5 {
            let (r, t) = fits[5 * m + j];
            let mut without = w[5 * m..5 * m + 5].to_vec();
            without[j] = 0.0;
            if !(w[5 * m + j] > 0.0 && without.iter().sum::<f64>() >= 3.0) {
                assert!(
                    r.iter().chain(&t).all(|v| v.is_nan()),
                    "set {m} neighbour {j}"
                );
                continue;
            }
            let (re, te) =
                rigid_motions(&a[5 * m..5 * m + 5], &b[5 * m..5 * m + 5], &without, 5)[0];
            for (got, expect) in r.iter().chain(&t).zip(re.iter().chain(&te)) {
                assert_eq!(got.to_bits(), expect.to_bits(), "set {m} neighbour {j}");
            }
        }
    }
}

#[test]
fn the_outlier_is_missed_and_the_others_fit() {
    let (a, b, w) = sets();
    let fits = rigid_held_out(&a, &b, &w, 5, 3.0);
    // Left out, the outlier is missed by about its offset (0.5); the others, fitted with
    // it among their neighbours, by less.
    let out = miss(&fits[3], a[3], b[3]);
    assert!(out > 0.3, "{out}");
    for j in [0, 1, 2, 4] {
        assert!(miss(&fits[j], a[j], b[j]) < out, "{j}");
    }
    // The second set: neighbours 6 and 9 not chosen; each chosen one leaves only 2 others.
    assert!(fits[5..].iter().all(|(r, _)| r[0].is_nan()));
    // With two others enough, the chosen ones are fitted (two points leave a rotation
    // about their line free: the fit exists, its miss is not asked about).
    let loose = rigid_held_out(&a, &b, &w, 5, 2.0);
    for j in [5, 7, 8] {
        assert!(
            loose[j].0.iter().chain(&loose[j].1).all(|v| v.is_finite()),
            "{j}"
        );
    }
    assert!(loose[6].0[0].is_nan() && loose[9].0[0].is_nan());
}

#[test]
fn no_sets_give_no_fits() {
    assert!(rigid_held_out(&[], &[], &[], 4, 3.0).is_empty());
    assert!(rigid_held_out(&[], &[], &[], 0, 3.0).is_empty());
}
