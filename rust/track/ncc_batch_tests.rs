//! Tests of the correlation at candidates across many images ([`super::ncc_at_cameras`]):
//! every row is [`super::ncc_at`]'s, to the bit, whatever the thread count.

use super::*;
use crate::lsm::ImageView;

/// A smooth texture of `width x height` (sum of sines with a per-image phase).
fn texture(width: usize, height: usize, phase: f64) -> Vec<f32> {
    let mut data = Vec::with_capacity(width * height);
    for v in 0..height {
        for u in 0..width {
            let (x, y) = (u as f64, v as f64);
            let g = 40.0 * (0.31 * x + 0.17 * y + phase).sin()
                + 30.0 * (-0.23 * x + 0.29 * y + 2.0 * phase).sin()
                + 20.0 * (0.47 * x + 0.07 * y + 3.0 * phase).sin();
            data.push((128.0 + g) as f32);
        }
    }
    data
}

#[test]
fn every_row_scores_as_ncc_at_does_to_the_bit() {
    let sizes = [(60, 50), (73, 41), (52, 66)];
    let templates: Vec<Vec<f32>> = sizes
        .iter()
        .enumerate()
        .map(|(k, &(w, h))| texture(w, h, 0.4 * k as f64))
        .collect();
    let searches: Vec<Vec<f32>> = sizes
        .iter()
        .enumerate()
        .map(|(k, &(w, h))| {
            let mut image = texture(w, h, 0.4 * k as f64 + 0.05);
            // A flat corner: NaN scores there.
            for v in 0..12 {
                image[v * w..v * w + 12].fill(90.0);
            }
            image
        })
        .collect();
    let view = |k: usize, data: &'static [f32]| ImageView {
        data,
        width: sizes[k].0,
        height: sizes[k].1,
    };
    let templates: Vec<&'static [f32]> = templates.into_iter().map(|t| &*t.leak()).collect();
    let searches: Vec<&'static [f32]> = searches.into_iter().map(|s| &*s.leak()).collect();
    let t: Vec<ImageView<'_>> = (0..3).map(|k| view(k, templates[k])).collect();
    let s: Vec<ImageView<'_>> = (0..3).map(|k| view(k, searches[k])).collect();
    let (n, k) = (40, 9);
    let cameras: Vec<usize> = (0..n).map(|i| (i * 7) % 3).collect();
    // Points inside, at and beyond the border; candidates at integer and sub-pixel centres.
    let points: Vec<[f64; 2]> = (0..n)
        .map(|i| [(i * 13 % 70) as f64 - 3.0, (i * 11 % 60) as f64 - 2.5])
        .collect();
    let candidates: Vec<[f64; 2]> = (0..n * k)
        .map(|j| {
            let p = points[j / k];
            [p[0] + (j % 3) as f64 - 1.0, p[1] + 0.5 * (j % k / 3) as f64]
        })
        .collect();
    let mut want = vec![0.0; n * k];
    for i in 0..n {
        let c = cameras[i];
        ncc_at(
            &t[c],
            points[i],
            &s[c],
            &candidates[i * k..(i + 1) * k],
            7,
            &mut want[i * k..(i + 1) * k],
        );
    }
    assert!(want.iter().any(|x| x.is_nan()) && want.iter().any(|x| *x > 0.9));
    for threads in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let mut got = vec![0.0; n * k];
        pool.install(|| ncc_at_cameras(&t, &s, &cameras, &points, &candidates, 7, &mut got))
            .unwrap();
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&got), bits(&want), "{threads} threads");
    }
}

#[test]
fn bad_indices_and_lengths_are_refused() {
    let data = texture(30, 30, 0.0);
    let image = ImageView {
        data: &data,
        width: 30,
        height: 30,
    };
    let points = [[15.0, 15.0]; 2];
    let candidates = [[15.0, 15.0]; 4];
    let mut scores = [0.0; 4];
    let run = |cameras: &[usize], candidates: &[[f64; 2]], scores: &mut [f64], searches: usize| {
        ncc_at_cameras(
            &[image],
            &vec![image; searches],
            cameras,
            &points,
            candidates,
            7,
            scores,
        )
    };
    assert!(run(&[0, 0], &candidates, &mut scores, 1).is_ok());
    assert!(matches!(
        run(&[0, 1], &candidates, &mut scores, 1),
        Err(crate::Error::IndexOutOfRange {
            argument: "cameras",
            row: 1,
            ..
        })
    ));
    assert!(matches!(
        run(&[0], &candidates, &mut scores, 1),
        Err(crate::Error::LengthMismatch {
            argument: "cameras",
            ..
        })
    ));
    assert!(matches!(
        run(&[0, 0], &candidates[..3], &mut scores, 1),
        Err(crate::Error::LengthMismatch {
            argument: "candidates",
            ..
        })
    ));
    assert!(matches!(
        run(&[0, 0], &candidates, &mut scores, 2),
        Err(crate::Error::LengthMismatch {
            argument: "searches",
            ..
        })
    ));
}
