//! Properties of the slave over random input (SPEC §1–§5).

mod common;
use common::*;
use modbus_drive::dictionary::{Access, DataType, PA_BASE, TABLE};
use modbus_drive::params::{PA, PA_COUNT};
use proptest::prelude::*;

/// Addresses that matter: broadcast, ours (1), another, and the never-used
/// 248..=255.
fn any_address() -> impl Strategy<Value = u8> {
    prop_oneof![Just(0u8), Just(1u8), Just(2u8), 248u8..=255, any::<u8>()]
}

/// Start addresses near entries, the legacy map and anywhere.
fn any_start() -> impl Strategy<Value = u16> {
    prop_oneof![
        proptest::sample::select(TABLE.iter().map(|e| e.index()).collect::<Vec<_>>()),
        (0u16..0x00B0),
        any::<u16>(),
    ]
}

/// A frame with a good CRC, a corrupted one or plain noise.
fn any_chunk() -> impl Strategy<Value = Vec<u8>> {
    let pdu = prop_oneof![
        (any_start(), 0u16..130).prop_map(|(s, q)| {
            let mut p = vec![0x03];
            p.extend_from_slice(&s.to_be_bytes());
            p.extend_from_slice(&q.to_be_bytes());
            p
        }),
        (any_start(), proptest::collection::vec(any::<u16>(), 0..20))
            .prop_map(|(s, w)| write_pdu(s, &w)),
        (any_start(), any::<u16>()).prop_map(|(s, v)| {
            let mut p = vec![0x06];
            p.extend_from_slice(&s.to_be_bytes());
            p.extend_from_slice(&v.to_be_bytes());
            p
        }),
        proptest::collection::vec(any::<u8>(), 1..12),
    ];
    prop_oneof![
        (any_address(), pdu.clone()).prop_map(|(a, p)| frame(a, &p)),
        (any_address(), pdu, any::<u8>()).prop_map(|(a, p, x)| {
            let mut f = frame(a, &p);
            let n = f.len();
            f[n - 1] ^= x | 1;
            f
        }),
        proptest::collection::vec(any::<u8>(), 0..40),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// Any bytes with any gaps: no panic, and every reply is a well-formed
    /// frame from our address (never to a broadcast or foreign address).
    #[test]
    fn any_stream_never_panics_nor_answers_others(
        chunks in proptest::collection::vec((any_chunk(), 0u32..4000, 0u32..3000), 1..12),
        pa54 in 0u16..=1,
        pa55 in 0u16..=1,
        pa52 in proptest::sample::select(vec![0u16, 4]),
    ) {
        let mut bus = Bus::with_params(|pa| {
            pa.set_unchecked(52, pa52);
            pa.set_unchecked(54, pa54);
            pa.set_unchecked(55, pa55);
        });
        for (bytes, gap_before, inner_gap) in chunks {
            let n = bytes.len();
            // one random inner gap somewhere in the chunk
            let at = if n == 0 { 0 } else { (inner_gap as usize) % n };
            bus.feed_gapped(bytes.into_iter().enumerate().map(|(i, b)| {
                (b, if i == 0 { gap_before } else if i == at { inner_gap / 2 } else { 0 })
            }));
            bus.idle(gap_before % 5000);
        }
        bus.idle(50_000);
        let own = bus.device.address();
        for s in &bus.sent {
            prop_assert!(s.bytes.len() >= 5);
            prop_assert_eq!(modbus_drive::rtu::crc16(&s.bytes), 0);
            prop_assert_eq!(s.bytes[0], own, "reply {:02X?}", s.bytes);
            // SPEC §2: only a frame addressed to us (never 0, never another
            // address, whatever the reply says) is answered.
            prop_assert_eq!(s.request_address, Some(own), "reply {:02X?}", s.bytes);
        }
    }

    /// A write that gets an exception changes no entry, no parameter.
    #[test]
    fn a_rejected_write_changes_nothing(
        start in any_start(),
        words in proptest::collection::vec(any::<u16>(), 0..30),
        single in any::<bool>(),
        busy in any::<bool>(),
        order in 0u16..=1,
    ) {
        let mut bus = Bus::new();
        bus.device.configure(|_, od| od.set_word_order(order));
        bus.device.set_storage_busy(busy);
        let pdu = if single {
            let mut p = vec![0x06];
            p.extend_from_slice(&start.to_be_bytes());
            p.extend_from_slice(&words.first().copied().unwrap_or(0).to_be_bytes());
            p
        } else {
            write_pdu(start, &words)
        };
        let od = bus.device.od().clone();
        let pa = bus.device.params().clone();
        let reply = bus.request(1, &pdu).expect("a unicast request is answered");
        if reply[1] & 0x80 != 0 {
            prop_assert_eq!(bus.device.od(), &od);
            prop_assert_eq!(bus.device.params(), &pa);
        } else {
            prop_assert!(!busy);
        }
    }

    /// Every RW entry reads back what was written, in both word orders.
    #[test]
    fn read_after_write_for_every_rw_entry(
        raws in proptest::collection::vec(any::<u32>(), TABLE.len()),
        order in 0u16..=1,
    ) {
        let mut bus = Bus::new();
        prop_assert_eq!(bus.write_single(0x6000, order), Ok(()));
        for (e, raw) in TABLE.iter().zip(raws) {
            if e.access() != Access::Rw {
                continue;
            }
            // Pick a value in range: the raw value if it is, else a fixed one.
            let raw = match e.data_type() {
                DataType::U16 | DataType::I16 => raw & 0xFFFF,
                _ => raw,
            };
            let raw = if e.index() == 0x6000 {
                u32::from(order)
            } else if e.object().accepts(raw) {
                raw
            } else {
                1
            };
            prop_assert!(e.object().accepts(raw));
            let (hi, lo) = ((raw >> 16) as u16, raw as u16);
            let wire = match (e.words(), order) {
                (1, _) => vec![lo],
                (_, 0) => vec![hi, lo],
                _ => vec![lo, hi],
            };
            prop_assert_eq!(bus.write(e.index(), &wire), Ok(()), "{:#06x}", e.index());
            prop_assert_eq!(bus.read(e.index(), e.words()), Ok(wire.clone()), "{:#06x}", e.index());
            if e.words() == 1 {
                prop_assert_eq!(bus.write_single(e.index(), lo), Ok(()));
                prop_assert_eq!(bus.read(e.index(), 1), Ok(wire));
            }
        }
    }

    /// Every RW parameter of the legacy PA block reads back what was written.
    #[test]
    fn read_after_write_for_every_rw_parameter(seeds in proptest::collection::vec(any::<u16>(), PA_COUNT)) {
        let mut bus = Bus::new();
        let mut expect = bus.device.params().as_array().to_vec();
        for (n, seed) in seeds.into_iter().enumerate() {
            let d = PA[n];
            if d.read_only() || n == 51 || n == 52 || n == 53 {
                continue; // address and line: see tests/addressing.rs
            }
            let span = u32::from(d.max() - d.min()) + 1;
            let mut v = d.min() + (u32::from(seed) % span) as u16;
            if !d.contains(v) {
                v = d.max(); // a gap in the range (PA17: 0 or 100..=65535)
            }
            prop_assert_eq!(bus.write_single(PA_BASE + n as u16, v), Ok(()));
            expect[n] = v;
        }
        let all = bus.read(PA_BASE, PA_COUNT as u16);
        prop_assert_eq!(all, Ok(expect));
    }
}

/// Diagnostics requests (0x08) of every sub-function and data word a
/// test below sends: 0x04 (listen-only) among them, well-formed or not.
fn any_diagnostics() -> impl Strategy<Value = Vec<u8>> {
    (
        0u16..0x16,
        prop_oneof![Just(0u16), Just(0xFF00), any::<u16>()],
    )
        .prop_map(|(sub, data)| {
            let mut p = vec![0x08];
            p.extend_from_slice(&sub.to_be_bytes());
            p.extend_from_slice(&data.to_be_bytes());
            p
        })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    /// `Device::will_answer_at_once`, told before the frame is handled,
    /// is what handling it then does: true exactly for a frame that gets
    /// a reply (or an EE request's deferred one) due t3.5 after it, but
    /// for a request to enter listen-only mode, which may be malformed
    /// and get an exception. The firmware raises the transceiver's DE on
    /// it before the reply exists, so a reply it does not foresee is
    /// only later, and a foreseen one that never comes a driver held for
    /// nothing.
    #[test]
    fn a_reply_is_foreseen_exactly(
        frames in proptest::collection::vec(
            (prop_oneof![any_chunk(), (any_address(), any_diagnostics()).prop_map(|(a, p)| frame(a, &p))],
             any::<bool>()),
            1..8),
        pa54 in 0u16..=1,
        pa55 in 0u16..=1,
        pa56 in prop_oneof![Just(0u16), 1u16..=3],
    ) {
        let mut bus = Bus::with_params(|pa| {
            pa.set_unchecked(54, pa54);
            pa.set_unchecked(55, pa55);
            pa.set_unchecked(56, pa56);
        });
        let mut reply = [0u8; modbus_drive::rtu::MAX_FRAME];
        for (bytes, parity_error) in frames {
            if bytes.len() < 4 {
                continue; // the assembler never closes such a frame
            }
            let ev = modbus_drive::rtu::RxEvent::Frame { bytes: &bytes, parity_error };
            let foreseen = bus.device.will_answer_at_once(&ev);
            let enters_listen_only = !parity_error
                && modbus_drive::rtu::crc16(&bytes) == 0
                && bytes.get(1..4) == Some(&[0x08, 0x00, 0x04][..]);
            let response = bus.device.handle_rx(ev, &mut reply);
            let answered = matches!(response, modbus_drive::device::Response::Reply(_))
                || bus.device.pending_ee().is_some();
            prop_assert_eq!(
                foreseen,
                answered && pa56 == 0 && !enters_listen_only,
                "{:02X?} parity {}", bytes, parity_error
            );
            bus.device.reply_sent();
            if bus.device.pending_ee().is_some() {
                bus.device.refuse_storage(&mut reply);
                bus.device.reply_sent();
            }
        }
    }
}
