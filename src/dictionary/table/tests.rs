//! The table's look-ups against a walk of it, its ranges and defaults.

use super::*;

#[test]
fn object_discriminants_are_table_positions_and_lookup_agrees() {
    for (i, e) in TABLE.iter().enumerate() {
        assert_eq!(e.object() as usize, i);
        assert_eq!(position(e.index()), Some(i));
    }
    // SPEC §5: 0x6090 and the legacy addresses are not entries.
    for a in [
        0x6090, 0x0000, 0x0064, 0x6082, 0x607B, 0x6067, 0x60F5, 0xFFFF,
    ] {
        assert_eq!(position(a), None);
    }
}

#[test]
fn ranges_of_section_5_2_step_8() {
    use Object::*;
    assert!(WordOrder.accepts(0) && WordOrder.accepts(1) && !WordOrder.accepts(2));
    for m in [1, 3, 6] {
        assert!(ModeOfOperation.accepts(m));
    }
    for m in [0, 2, 4, 5, 7, 0xFFFF] {
        assert!(!ModeOfOperation.accepts(m), "mode {m}");
    }
    assert!(HomingMethod.accepts(1) && HomingMethod.accepts(8));
    assert!(!HomingMethod.accepts(0) && !HomingMethod.accepts(9));
    assert!(QuickStopOption.accepts(0) && QuickStopOption.accepts(0x7FFF));
    assert!(!QuickStopOption.accepts(0x8000) && !QuickStopOption.accepts(0xFFFF));
    assert!(HomingSpeed.accepts(100_001) && ProfileVelocity.accepts(u32::MAX));
}

#[test]
fn defaults_are_what_a_fresh_dictionary_reads() {
    struct Idle;
    impl DriveLayer for Idle {
        fn statusword(&self) -> u16 {
            0
        }
        fn mode_display(&self) -> i16 {
            0
        }
        fn actual_position(&self) -> i32 {
            0
        }
        fn actual_velocity_rpm(&self) -> i32 {
            0
        }
        fn error_register(&self) -> u16 {
            0
        }
        fn values_written(&mut self, _: super::super::Config<'_>) {}
        fn mode_written(&mut self, _: i16, _: super::super::Config<'_>) {}
        fn controlword_written(&mut self, _: u16, _: super::super::Config<'_>) {}
    }
    let od = OdValues::default();
    for e in TABLE {
        assert_eq!(e.object().read_raw(&od, &Idle) as i32, e.default(), "{e:?}");
    }
}

/// The entries a request of `quantity` words from `first` covers, by
/// walking the table word by word (what `Span` finds with look-ups).
fn walk(first: usize, quantity: u16) -> Option<core::ops::Range<usize>> {
    let (mut at, mut p) = (0, first);
    while at < usize::from(quantity) {
        at += usize::from(TABLE.get(p)?.words());
        p += 1;
    }
    (at == usize::from(quantity)).then_some(first..p)
}

#[test]
fn spans_agree_with_a_walk_of_the_table() {
    // SPEC §5.2 steps 6 and 7: a request must end on an entry boundary
    // inside the table; its access is that of every entry it covers.
    for first in 0..TABLE.len() {
        for quantity in 0..=60 {
            let span = Span::new(first, quantity);
            let Some(range) = walk(first, quantity) else {
                assert_eq!(span, None, "first {first} quantity {quantity}");
                continue;
            };
            let span = span.expect("the walk found a span");
            let entries = &TABLE[range.clone()];
            assert_eq!(span.entries(), entries);
            assert_eq!(
                span.any_read_only(),
                entries.iter().any(|e| e.access() == Access::Ro)
            );
            assert_eq!(
                span.any_write_only(),
                entries.iter().any(|e| e.access() == Access::Wo)
            );
            for e in TABLE {
                assert_eq!(
                    span.covers(e.object()),
                    range.contains(&(e.object() as usize))
                );
            }
            let mut word = 0;
            let mut ranged = std::vec::Vec::new();
            for e in entries {
                if e.object().ranged() {
                    ranged.push((e.object(), word));
                }
                word += usize::from(e.words());
            }
            let found: std::vec::Vec<_> = span.ranged().map(|(e, w)| (e.object(), w)).collect();
            assert_eq!(found, ranged, "first {first} quantity {quantity}");
        }
    }
}

#[test]
fn only_ranged_one_word_entries_refuse_values() {
    // `Registers::write` checks §5.2 step 8 on the ranged entries only,
    // reading one word for each.
    for e in TABLE {
        if e.object().ranged() {
            assert_eq!(e.words(), 1, "{e:?}");
        } else {
            for raw in [0, 1, 0x7FFF, 0x8000, 0xFFFF, 0x1_0000, u32::MAX] {
                assert!(e.object().accepts(raw), "{e:?} {raw:#x}");
            }
        }
    }
}

#[test]
fn strings_are_cut_and_nul_padded() {
    assert_eq!(&string_bytes("ab")[..3], b"ab\0");
    assert_eq!(string_bytes("0123456789abcdefXYZ"), *b"0123456789abcdef");
}
