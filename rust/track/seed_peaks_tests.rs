use super::*;

#[test]
fn the_best_and_the_best_peak_away_from_it() {
    // Local maxima at 2 (0.9, the best), 6 (0.7, 4 samples away) and 9 (0.8, 7 away; the
    // last sample, its missing neighbour -inf).
    let s = [0.1, 0.5, 0.9, 0.4, 0.2, 0.3, 0.7, 0.1, 0.6, 0.8];
    let uv = vec![[0.0; 2]; s.len()];
    assert_eq!(line_peak(&s, &uv, Away::Samples(3)), (2, 0.9, 0.8));
    // More than 6 samples away: 9 only; more than 7: none.
    assert_eq!(line_peak(&s, &uv, Away::Samples(6)), (2, 0.9, 0.8));
    assert_eq!(
        line_peak(&s, &uv, Away::Samples(7)),
        (2, 0.9, f64::NEG_INFINITY)
    );
}

#[test]
fn ties_take_the_first_and_plateaus_are_peaks() {
    let s = [0.5, 0.9, 0.9, 0.2, 0.2, 0.2, 0.1];
    let uv = vec![[0.0; 2]; s.len()];
    // argmax's first index (1). Equal neighbours do not stop a local maximum: 2 (0.9), 4
    // and 5 (0.2) are ones; 3 (0.2 beside 0.9) is not.
    assert_eq!(line_peak(&s, &uv, Away::Samples(2)), (1, 0.9, 0.2));
    // The second sample of the best plateau is a local maximum but near the best.
    assert_eq!(line_peak(&s, &uv, Away::Samples(0)), (1, 0.9, 0.9));
}

#[test]
fn unscored_samples_are_minus_infinity_and_never_peaks() {
    let n = f64::NAN;
    let s = [n, f64::INFINITY, 0.3, n, f64::NEG_INFINITY, 0.2, n];
    let uv = vec![[0.0; 2]; s.len()];
    // inf is not finite: -inf. 0.3 at 2 is the best; 0.2 at 5 a peak 3 samples away.
    assert_eq!(line_peak(&s, &uv, Away::Samples(2)), (2, 0.3, 0.2));
    let none = [n, n, n];
    let (best, peak, second) = line_peak(&none, &uv[..3], Away::Samples(0));
    assert_eq!(
        (best, peak, second),
        (0, f64::NEG_INFINITY, f64::NEG_INFINITY)
    );
}

#[test]
fn apart_in_pixels() {
    let s = [0.2, 0.9, 0.1, 0.8, 0.1, 0.7];
    // Samples 1.5 px apart along u: 3 lies 3 px from the best (1), 5 lies 6 px.
    let uv: Vec<[f64; 2]> = (0..6).map(|i| [1.5 * i as f64, 10.0]).collect();
    assert_eq!(line_peak(&s, &uv, Away::Pixels(3.0)), (1, 0.9, 0.7));
    assert_eq!(line_peak(&s, &uv, Away::Pixels(2.9)), (1, 0.9, 0.8));
    assert_eq!(
        line_peak(&s, &uv, Away::Pixels(6.0)),
        (1, 0.9, f64::NEG_INFINITY)
    );
}
