//! The synthesizer's integration tests, one test binary: scenes written and read back in the
//! dataset format, and their geometry against the ray caster.

mod dataset;
mod geometry;
