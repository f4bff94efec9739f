//! A disk cache of the networks' results, for tracker studies: the same image always gives
//! the same features and the same two feature sets the same matches, so a study that
//! re-runs the tracker on the same clips (`tools/clip_study.py` with `SUPERMVO_NETWORK_CACHE`
//! set) computes each only once. Results are keyed by a SHA-256 of the inputs and a tag
//! that names the front end and its settings; a changed tracker that asks for other pairs
//! computes them and adds them. Off unless asked for: runs users make never read it.

use crate::{Extractor, Features, GrayImage, InferenceError, Matcher, Matches};
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};

/// An [`Extractor`] or [`Matcher`] whose results are kept in (and read from) a folder.
pub struct Cached<T> {
    inner: T,
    dir: PathBuf,
    tag: String,
}

impl<T> std::fmt::Debug for Cached<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Cached({}, {})", self.dir.display(), self.tag)
    }
}

impl<T> Cached<T> {
    /// `inner` with its results cached in `dir` under `tag` (the front end and every setting
    /// that changes its output).
    pub fn new(inner: T, dir: &Path, tag: &str) -> Self {
        Self {
            inner,
            dir: dir.to_path_buf(),
            tag: tag.to_string(),
        }
    }

    fn path(&self, kind: &str, parts: &[&[u8]]) -> PathBuf {
        let mut h = Sha256::new();
        h.update(kind.as_bytes());
        h.update(self.tag.as_bytes());
        for p in parts {
            h.update((p.len() as u64).to_le_bytes());
            h.update(p);
        }
        let hex: String = h.finalize()[..16]
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect();
        self.dir.join(format!("{kind}-{hex}.bin"))
    }
}

/// Writes `bytes` to `path` through a temporary file, so a reader never sees half a file;
/// a cache that cannot be written is only slower, so failures are logged, not returned.
fn store(path: &Path, bytes: &[u8]) {
    let tmp = path.with_extension(format!("tmp{}", std::process::id()));
    let written = path
        .parent()
        .map_or(Ok(()), std::fs::create_dir_all)
        .and_then(|_| std::fs::write(&tmp, bytes))
        .and_then(|_| std::fs::rename(&tmp, path));
    if let Err(e) = written {
        tracing::warn!(path = %path.display(), error = %e, "network cache not written");
    }
}

fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// Little-endian words read one after the other; `None` past the end.
struct Reader<'a>(&'a [u8]);

impl Reader<'_> {
    fn u64(&mut self) -> Option<u64> {
        let (head, rest) = self.0.split_first_chunk::<8>()?;
        self.0 = rest;
        Some(u64::from_le_bytes(*head))
    }
    fn f32s(&mut self, n: usize) -> Option<Vec<f32>> {
        let bytes = n.checked_mul(4)?;
        if self.0.len() < bytes {
            return None;
        }
        let (head, rest) = self.0.split_at(bytes);
        self.0 = rest;
        Some(
            head.chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
        )
    }
}

fn encode_features(f: &Features) -> Vec<u8> {
    let mut out = Vec::new();
    for v in [f.len(), f.dim, f.image_size.0, f.image_size.1] {
        out.extend((v as u64).to_le_bytes());
    }
    let flat: Vec<f32> = f.keypoints.iter().flatten().copied().collect();
    out.extend(f32_bytes(&flat));
    out.extend(f32_bytes(&f.scores));
    out.extend(f32_bytes(&f.descriptors));
    out
}

fn decode_features(bytes: &[u8]) -> Option<Features> {
    let mut r = Reader(bytes);
    let (n, dim, w, h) = (
        r.u64()? as usize,
        r.u64()? as usize,
        r.u64()? as usize,
        r.u64()? as usize,
    );
    let flat = r.f32s(n.checked_mul(2)?)?;
    let scores = r.f32s(n)?;
    let descriptors = r.f32s(n.checked_mul(dim)?)?;
    r.0.is_empty().then(|| Features {
        keypoints: flat.chunks_exact(2).map(|c| [c[0], c[1]]).collect(),
        scores,
        descriptors,
        dim,
        image_size: (w, h),
    })
}

fn encode_matches(m: &Matches) -> Vec<u8> {
    let mut out = (m.pairs.len() as u64).to_le_bytes().to_vec();
    for &(a, b) in &m.pairs {
        out.extend((a as u64).to_le_bytes());
        out.extend((b as u64).to_le_bytes());
    }
    out.extend(f32_bytes(&m.scores));
    out
}

fn decode_matches(bytes: &[u8]) -> Option<Matches> {
    let mut r = Reader(bytes);
    let n = r.u64()? as usize;
    let mut pairs = Vec::with_capacity(n.min(1 << 20));
    for _ in 0..n {
        pairs.push((r.u64()? as usize, r.u64()? as usize));
    }
    let scores = r.f32s(n)?;
    r.0.is_empty().then_some(Matches { pairs, scores })
}

impl<E: Extractor> Extractor for Cached<E> {
    fn extract(&mut self, image: &GrayImage) -> Result<Features, InferenceError> {
        let size = [image.width as u64, image.height as u64];
        let size: Vec<u8> = size.iter().flat_map(|v| v.to_le_bytes()).collect();
        let path = self.path("features", &[&size, &image.data]);
        if let Some(f) = std::fs::read(&path).ok().and_then(|b| decode_features(&b)) {
            return Ok(f);
        }
        let f = self.inner.extract(image)?;
        store(&path, &encode_features(&f));
        Ok(f)
    }
}

impl<M: Matcher> Matcher for Cached<M> {
    fn match_features(&mut self, a: &Features, b: &Features) -> Result<Matches, InferenceError> {
        let path = self.path("matches", &[&encode_features(a), &encode_features(b)]);
        if let Some(m) = std::fs::read(&path).ok().and_then(|b| decode_matches(&b)) {
            return Ok(m);
        }
        let m = self.inner.match_features(a, b)?;
        store(&path, &encode_matches(&m));
        Ok(m)
    }

    fn warm_up(&mut self, a: &Features, b: &Features) -> Result<(), InferenceError> {
        self.inner.warm_up(a, b)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)] // test code
    use super::*;

    /// Counts its calls; features depend on the image, matches on both sets.
    struct Counting(usize);

    impl Extractor for Counting {
        fn extract(&mut self, image: &GrayImage) -> Result<Features, InferenceError> {
            self.0 += 1;
            let v = image.data[0] as f32;
            Ok(Features {
                keypoints: vec![[v, 1.5], [2.0, v]],
                scores: vec![0.9, 0.1],
                descriptors: vec![v, 0.0, 1.0, -v],
                dim: 2,
                image_size: (image.width, image.height),
            })
        }
    }

    impl Matcher for Counting {
        fn match_features(
            &mut self,
            a: &Features,
            b: &Features,
        ) -> Result<Matches, InferenceError> {
            self.0 += 1;
            Ok(Matches {
                pairs: vec![
                    (0, a.keypoints[0][0] as usize),
                    (1, b.keypoints[0][0] as usize),
                ],
                scores: vec![0.5, 0.25],
            })
        }
    }

    fn image(v: u8) -> GrayImage {
        GrayImage {
            width: 2,
            height: 1,
            data: vec![v, 0],
        }
    }

    #[test]
    fn results_come_back_identical_and_are_computed_once() {
        let dir = tempfile::tempdir().unwrap();
        let mut ex = Cached::new(Counting(0), dir.path(), "t");
        let mut m = Cached::new(Counting(0), dir.path(), "t");
        let (a, b) = (
            ex.extract(&image(3)).unwrap(),
            ex.extract(&image(7)).unwrap(),
        );
        let ab = m.match_features(&a, &b).unwrap();
        // a second cache on the same folder reads them back without computing
        let mut ex2 = Cached::new(Counting(0), dir.path(), "t");
        let mut m2 = Cached::new(Counting(0), dir.path(), "t");
        assert_eq!(ex2.extract(&image(3)).unwrap(), a);
        assert_eq!(ex2.extract(&image(7)).unwrap(), b);
        assert_eq!(m2.match_features(&a, &b).unwrap(), ab);
        assert_eq!((ex2.inner.0, m2.inner.0), (0, 0));
        // other inputs, the pair reversed or another tag are computed
        ex2.extract(&image(4)).unwrap();
        m2.match_features(&b, &a).unwrap();
        let mut other = Cached::new(Counting(0), dir.path(), "u");
        other.extract(&image(3)).unwrap();
        assert_eq!((ex2.inner.0, m2.inner.0, other.inner.0), (1, 1, 1));
    }

    #[test]
    fn a_damaged_file_is_computed_again() {
        let dir = tempfile::tempdir().unwrap();
        let mut ex = Cached::new(Counting(0), dir.path(), "t");
        let f = ex.extract(&image(3)).unwrap();
        for entry in std::fs::read_dir(dir.path()).unwrap() {
            let p = entry.unwrap().path();
            let bytes = std::fs::read(&p).unwrap();
            std::fs::write(&p, &bytes[..bytes.len() - 3]).unwrap();
        }
        assert_eq!(ex.extract(&image(3)).unwrap(), f);
        assert_eq!(ex.inner.0, 2);
    }
}
