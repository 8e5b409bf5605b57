//! Nothing but the benches (`benches/instructions.rs`, run by ../run-host.sh).
