//! A pipeline stage: a library type with typed input and output that knows nothing about
//! transport, so the same code runs in-process (tests, `supermvo run`) or in its own
//! process. [`Timed`] runs a stage and records the duration of every call.

use std::time::Instant;

/// One step of the pipeline.
pub trait Stage {
    /// What the stage consumes.
    type Input;
    /// What it produces.
    type Output;
    /// Error type.
    type Error;
    /// Stage name, for timing reports.
    fn name(&self) -> &'static str;
    /// Processes one input.
    fn process(&mut self, input: Self::Input) -> Result<Self::Output, Self::Error>;
}

/// Runs a stage and keeps the duration of each call in milliseconds.
#[derive(Debug)]
pub struct Timed<S> {
    stage: S,
    durations_ms: Vec<f64>,
}

impl<S: Stage> Timed<S> {
    /// Wraps a stage.
    pub fn new(stage: S) -> Self {
        Self {
            stage,
            durations_ms: Vec::new(),
        }
    }

    /// Calls the stage, timing it.
    pub fn call(&mut self, input: S::Input) -> Result<S::Output, S::Error> {
        let t = Instant::now();
        let out = self.stage.process(input);
        self.durations_ms.push(t.elapsed().as_secs_f64() * 1e3);
        out
    }

    /// Durations so far.
    pub fn durations_ms(&self) -> &[f64] {
        &self.durations_ms
    }

    /// The wrapped stage.
    pub fn inner(&self) -> &S {
        &self.stage
    }

    /// The wrapped stage, mutably.
    pub fn inner_mut(&mut self) -> &mut S {
        &mut self.stage
    }

    /// Median call duration in milliseconds (NaN before the first call).
    pub fn median_ms(&self) -> f64 {
        let mut v = self.durations_ms.clone();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Double;
    impl Stage for Double {
        type Input = u32;
        type Output = u32;
        type Error = ();
        fn name(&self) -> &'static str {
            "double"
        }
        fn process(&mut self, x: u32) -> Result<u32, ()> {
            Ok(2 * x)
        }
    }

    #[test]
    fn timed_records_every_call() {
        let mut t = Timed::new(Double);
        assert_eq!(t.call(3), Ok(6));
        assert_eq!(t.call(4), Ok(8));
        assert_eq!(t.durations_ms().len(), 2);
        assert_eq!(t.inner().name(), "double");
        assert!(t.median_ms() >= 0.0);
    }
}
