//! The dispatcher: frame in → reply bytes or silence, plus the §6 counters.
//! Filled by issue 2.
