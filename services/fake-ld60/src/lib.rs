//! Fake LD-60.
