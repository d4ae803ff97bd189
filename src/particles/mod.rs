//! ② Particles: the particle set and the filter steps (init, transition, likelihood, resampling, estimate).
