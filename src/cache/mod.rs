//! The content-addressed artifact cache (skeleton).
