//! Monitor statistics.
