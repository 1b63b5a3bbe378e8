//! The pipeline: chains the stages through the cache (being wired as the stages land).
