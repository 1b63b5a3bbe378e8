//! The pipeline: chains the stages through the cache (skeleton).
