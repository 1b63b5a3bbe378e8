//! A small deterministic generator of pseudo-random numbers (a 64-bit linear congruential
//! generator, Knuth's MMIX constants), for synthetic data and tests: the same seed gives the
//! same sequence on every machine.
//!
//! Input: a seed. Output: uniform numbers in [0, 1) from the state's top 53 bits, integers from
//! its top 31, and standard normal ones by Box–Muller.

/// A deterministic generator (64-bit LCG, top bits).
#[derive(Clone, Debug)]
pub struct Lcg(u64);

impl Lcg {
    /// A generator from a seed.
    pub fn new(seed: u64) -> Lcg {
        Lcg(seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407))
    }

    /// The next state.
    fn step(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        self.0
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.step() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// The next state's top 31 bits, as an integer (for picks and indices).
    #[cfg(test)] // only the unit tests call it
    pub(crate) fn bits31(&mut self) -> u64 {
        self.step() >> 33
    }

    /// Standard normal (Box–Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}
