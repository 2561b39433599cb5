//! What a long computation reports as it goes, so that a person is not left before a silent
//! terminal: the CLI draws a bar with rate and time left, a library user may ignore it.

/// A receiver of progress. Every method has a default that does nothing.
pub trait Progress: Sync {
    /// A new step of `total` units (rows, pairs, …) called `what`.
    fn begin(&self, _what: &str, _total: u64) {}
    /// `n` more units done.
    fn advance(&self, _n: u64) {}
    /// The step is over.
    fn end(&self) {}
}

/// Progress nobody watches.
pub struct Silent;
impl Progress for Silent {}

/// Progress whose steps are named with a prefix (`photos 1 × 2: `), for a step run per pair.
pub struct Prefixed<'a> {
    pub inner: &'a dyn Progress,
    pub prefix: String,
}

impl Progress for Prefixed<'_> {
    fn begin(&self, what: &str, total: u64) {
        self.inner.begin(&format!("{}{what}", self.prefix), total);
    }
    fn advance(&self, n: u64) {
        self.inner.advance(n);
    }
    fn end(&self) {
        self.inner.end();
    }
}
