//! Episode bookkeeping: resets, per-step errors and metrics.
