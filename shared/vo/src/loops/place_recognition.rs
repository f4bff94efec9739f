//! Place recognition: a VLAD vector per keyframe over a vocabulary learned at the start of
//! the run from the first keyframes' descriptors (k-means, fixed seed).

use super::LoopCloser;
use nalgebra::DMatrix;

impl LoopCloser {
    pub(super) fn update_vocabulary(&mut self) {
        if self.vocabulary.is_none() {
            if self.keyframes.len() < self.cfg.vocabulary_keyframes {
                return;
            }
            let rows: Vec<_> = self
                .keyframes
                .iter()
                .flat_map(|k| {
                    k.desc
                        .row_iter()
                        .step_by(2)
                        .map(|r| r.into_owned())
                        .collect::<Vec<_>>()
                })
                .collect();
            if rows.is_empty() {
                return;
            }
            let data = DMatrix::from_rows(&rows);
            let vocabulary = kmeans(&data, self.cfg.vocabulary_size, 10);
            tracing::debug!(
                words = vocabulary.nrows(),
                descriptors = rows.len(),
                "loop vocabulary trained"
            );
            self.vocabulary = Some(vocabulary);
        }
        if let Some(voc) = &self.vocabulary {
            for k in self
                .keyframes
                .iter_mut()
                .filter(|k| k.vlad.is_none() && !k.culled)
            {
                k.vlad = Some(vlad(&k.desc, voc));
            }
        }
    }
}

/// Deterministic k-means (k-means++ seeding from a fixed-seed generator, Lloyd iterations)
/// on unit descriptors; returns unit centres as rows.
pub(super) fn kmeans(data: &DMatrix<f32>, k: usize, iterations: usize) -> DMatrix<f32> {
    let (n, d) = (data.nrows(), data.ncols());
    let k = k.min(n).max(1);
    let mut rng = supermvo_geometry::rng::SplitMix64::new(0x5EED);
    let mut next = || rng.next_f64();
    let mut centres = DMatrix::<f32>::zeros(k, d);
    centres
        .row_mut(0)
        .copy_from(&data.row((next() * n as f64) as usize % n));
    let mut dist = vec![f32::MAX; n];
    for c in 1..k {
        for (i, di) in dist.iter_mut().enumerate() {
            let e = (data.row(i) - centres.row(c - 1)).norm_squared();
            *di = di.min(e);
        }
        let total: f64 = dist.iter().map(|&v| v as f64).sum();
        let mut target = next() * total;
        let mut pick = n - 1;
        for (i, &v) in dist.iter().enumerate() {
            target -= v as f64;
            if target <= 0.0 {
                pick = i;
                break;
            }
        }
        centres.row_mut(c).copy_from(&data.row(pick));
    }
    for _ in 0..iterations {
        let assign = nearest_rows(data, &centres);
        let mut sums = DMatrix::<f32>::zeros(k, d);
        for (i, &c) in assign.iter().enumerate() {
            let row = sums.row(c) + data.row(i);
            sums.row_mut(c).copy_from(&row);
        }
        for c in 0..k {
            let norm = sums.row(c).norm();
            if norm > 0.0 {
                let row = sums.row(c) / norm;
                centres.row_mut(c).copy_from(&row);
            }
        }
    }
    centres
}

pub(super) fn nearest_rows(data: &DMatrix<f32>, centres: &DMatrix<f32>) -> Vec<usize> {
    let sim = data * centres.transpose();
    (0..sim.nrows())
        .map(|i| {
            sim.row(i)
                .iter()
                .enumerate()
                .fold(
                    (0, f32::MIN),
                    |acc, (j, &v)| if v > acc.1 { (j, v) } else { acc },
                )
                .0
        })
        .collect()
}

/// VLAD: per word, the sum of residuals of the descriptors assigned to it; each word's block
/// normalised (intra-normalisation), then the whole vector.
pub(super) fn vlad(desc: &DMatrix<f32>, vocabulary: &DMatrix<f32>) -> Vec<f32> {
    let (k, d) = (vocabulary.nrows(), vocabulary.ncols());
    let mut v = vec![0.0f32; k * d];
    for (i, &c) in nearest_rows(desc, vocabulary).iter().enumerate() {
        for j in 0..d {
            v[c * d + j] += desc[(i, j)] - vocabulary[(c, j)];
        }
    }
    for block in v.chunks_mut(d) {
        let n = block.iter().map(|x| x * x).sum::<f32>().sqrt();
        if n > 0.0 {
            block.iter_mut().for_each(|x| *x /= n);
        }
    }
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    if n > 0.0 {
        v.iter_mut().for_each(|x| *x /= n);
    }
    v
}

pub(super) fn dot(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vlad_is_unit_and_discriminative() {
        let data =
            DMatrix::<f32>::from_fn(200, 8, |i, j| (((i * 7 + j * 3) % 11) as f32 - 5.0) / 5.0);
        let voc = kmeans(&data, 4, 5);
        assert_eq!(voc.nrows(), 4);
        let v1 = vlad(&data.rows(0, 100).into_owned(), &voc);
        let v2 = vlad(&data.rows(100, 100).into_owned(), &voc);
        assert!((dot(&v1, &v1) - 1.0).abs() < 1e-4);
        assert!(dot(&v1, &v2) <= 1.0 + 1e-4);
        // Deterministic.
        assert_eq!(kmeans(&data, 4, 5), voc);
    }
}
