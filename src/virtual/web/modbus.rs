//! The page's way into a drive: every read, edit and command is a Modbus
//! request frame addressed to the drive and handed to the same entry
//! ([`Device::poll`]) as a frame from the bus, so the page gets the
//! reply — and the exception code — a master would get.
//!
//! The page is a second port of the drive (a service port, as a USB or
//! front-panel port on a real drive): it has its own [`Slave`], so its
//! requests count in its own §6 counters and not in the bus's, and a bus put
//! in listen-only mode does not silence the page. Everything else is the
//! drive's: its address, its busy state, its PA55 exception profile, its
//! communication-loss timer (a valid request from either port feeds it: the
//! drive cannot tell which master is in charge).

use modbus_drive::device::{Line, Polled, Request};
use modbus_drive::rtu::{crc16, with_crc, LineConfig, RxEvent};
use modbus_drive::slave::Slave;
use modbus_drive::Device;

/// Function codes the page uses (SPEC §4).
pub const READ_HOLDING: u8 = 0x03;
pub const WRITE_SINGLE: u8 = 0x06;
pub const WRITE_MULTIPLE: u8 = 0x10;

/// Legacy register of the new-format EE operations (SPEC §9).
pub const EE_REGISTER: u16 = 0x003A;

/// What the drive answered one request.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Answer {
    /// A normal reply: its PDU (function code first, no address, no CRC).
    Ok(Vec<u8>),
    /// An exception reply with this code (as sent, after PA55).
    Exception(u8),
    /// No reply at all (the dispatcher stayed silent).
    Silent,
    /// A reply that is not a well-formed answer to the request.
    Malformed(Vec<u8>),
}

/// One request PDU (function code and data, no address, no CRC).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Pdu(pub Vec<u8>);

impl Pdu {
    /// 0x03 of `quantity` words at `start`.
    pub fn read(start: u16, quantity: u16) -> Self {
        let mut v = vec![READ_HOLDING];
        v.extend_from_slice(&start.to_be_bytes());
        v.extend_from_slice(&quantity.to_be_bytes());
        Self(v)
    }

    /// 0x06 of one word.
    pub fn write_single(address: u16, value: u16) -> Self {
        let mut v = vec![WRITE_SINGLE];
        v.extend_from_slice(&address.to_be_bytes());
        v.extend_from_slice(&value.to_be_bytes());
        Self(v)
    }

    /// 0x10 of `words` from `start`.
    pub fn write_multiple(start: u16, words: &[u16]) -> Self {
        let mut v = vec![WRITE_MULTIPLE];
        v.extend_from_slice(&start.to_be_bytes());
        v.extend_from_slice(&(words.len() as u16).to_be_bytes());
        v.push((2 * words.len()) as u8);
        for w in words {
            v.extend_from_slice(&w.to_be_bytes());
        }
        Self(v)
    }

    /// A 32-bit value as two words in the word order 0x6000 sets (SPEC §5.1).
    pub fn words32(value: u32, low_word_first: bool) -> [u16; 2] {
        let (hi, lo) = ((value >> 16) as u16, value as u16);
        if low_word_first {
            [lo, hi]
        } else {
            [hi, lo]
        }
    }

    pub fn function(&self) -> u8 {
        self.0.first().copied().unwrap_or(0)
    }

    /// The RTU frame to `address`: address, PDU, CRC.
    pub fn frame(&self, address: u8) -> Vec<u8> {
        let mut buf = vec![0u8; self.0.len() + 3];
        buf[0] = address;
        buf[1..=self.0.len()].copy_from_slice(&self.0);
        let n = with_crc(&mut buf, self.0.len() + 1);
        buf.truncate(n);
        buf
    }
}

/// Reads the reply frame to `request` sent to `address`.
pub fn parse_reply(address: u8, request: &Pdu, reply: &[u8]) -> Answer {
    if reply.is_empty() {
        return Answer::Silent;
    }
    if reply.len() < 5 || crc16(reply) != 0 || reply[0] != address {
        return Answer::Malformed(reply.to_vec());
    }
    let pdu = &reply[1..reply.len() - 2];
    if pdu[0] == request.function() | 0x80 && pdu.len() == 2 {
        Answer::Exception(pdu[1])
    } else if pdu[0] == request.function() {
        Answer::Ok(pdu.to_vec())
    } else {
        Answer::Malformed(reply.to_vec())
    }
}

/// The words of a 0x03 reply PDU.
#[cfg(test)]
pub fn read_words(pdu: &[u8]) -> Vec<u16> {
    pdu.get(2..)
        .unwrap_or(&[])
        .chunks_exact(2)
        .map(|c| u16::from_be_bytes([c[0], c[1]]))
        .collect()
}

/// What a drive must offer so that the page's requests take the bus path.
pub trait Dispatch {
    fn device(&mut self) -> &mut Device;
    /// Hands the page's frame on `line` to the drive ([`Device::poll`])
    /// with the drive's parameter flash.
    fn poll(&mut self, now_us: u64, line: &mut impl Line) -> Polled;
    /// Brings the axis and the control loop up to `now_us`: the drive acts
    /// on a frame at the time it arrives, as on the bus path.
    fn advance(&mut self, now_us: u64);
    /// The control call that follows every handled frame (SPEC §8).
    fn control_at(&mut self, now_us: u64);
}

/// The page as a line to the drive: one request, its reply taken at once
/// (the page waits for no reply delay), and the line change it made.
struct PageLine<'f> {
    frame: Option<&'f [u8]>,
    reply: Vec<u8>,
    line: Option<LineConfig>,
}

impl Line for PageLine<'_> {
    fn receive(&mut self) -> Option<Request<'_>> {
        let bytes = self.frame.take()?;
        Some(Request::new(
            RxEvent::Frame {
                bytes,
                parity_error: false,
            },
            None,
        ))
    }

    fn send(&mut self, bytes: &[u8], _at_us: u64) {
        self.reply = bytes.to_vec();
    }

    fn reconfigure(&mut self, line: LineConfig) {
        self.line = Some(line);
    }
}

/// Sends `request` to the drive through `port` (the page's own slave
/// state) and returns the answer, and the drive's new line format if the
/// request changed it (the caller puts it in force on the bus, as after a
/// bus reply).
pub fn transact<D: Dispatch>(
    drive: &mut D,
    port: &mut Slave,
    request: &Pdu,
    now_us: u64,
) -> (Answer, Option<LineConfig>) {
    drive.advance(now_us);
    let address = drive.device().address();
    let frame = request.frame(address);
    let mut page = PageLine {
        frame: Some(&frame),
        reply: Vec::new(),
        line: None,
    };
    // The exception 4 of a failed EE operation is counted on the port that
    // asked too: the port is swapped in for the whole request.
    drive.device().swap_slave(port);
    drive.poll(now_us, &mut page);
    drive.device().swap_slave(port);
    drive.control_at(now_us);
    (parse_reply(address, request, &page.reply), page.line)
}

#[cfg(test)]
mod tests {
    use super::*;
    use modbus_drive::device::Identity;
    use modbus_drive::dictionary::DriveLayer;
    use modbus_drive::motion::StepSchedule;
    use modbus_drive::params::{ParamStore, SimFlash};

    struct Bench {
        device: Device,
        store: ParamStore<SimFlash<2>>,
        schedule: StepSchedule,
        controls: u32,
    }

    impl Bench {
        fn new() -> Self {
            Self {
                device: Device::new(Identity::new("test")),
                store: ParamStore::new(SimFlash::<2>::new(), 0..4096).unwrap(),
                schedule: StepSchedule::new(),
                controls: 0,
            }
        }
    }

    impl Dispatch for Bench {
        fn device(&mut self) -> &mut Device {
            &mut self.device
        }
        fn poll(&mut self, now_us: u64, line: &mut impl Line) -> Polled {
            self.device.poll(now_us, line, &mut self.store)
        }
        fn advance(&mut self, _now_us: u64) {}
        fn control_at(&mut self, now_us: u64) {
            self.controls += 1;
            self.device
                .control(now_us, Default::default(), &self.schedule);
        }
    }

    #[test]
    fn frames_carry_the_address_and_a_crc_the_drive_accepts() {
        // SPEC §10: `01 06 60 90 00 03 D7 E6`.
        let f = Pdu::write_single(0x6090, 3).frame(1);
        assert_eq!(f, [0x01, 0x06, 0x60, 0x90, 0x00, 0x03, 0xD7, 0xE6]);
        // SPEC §5.1: 0x607A = 200000 in both word orders.
        let hi = Pdu::write_multiple(0x607A, &Pdu::words32(200_000, false)).frame(1);
        assert_eq!(hi, hex("01 10 60 7A 00 02 04 00 03 0D 40 29 96"));
        let lo = Pdu::write_multiple(0x607A, &Pdu::words32(200_000, true)).frame(1);
        assert_eq!(lo, hex("01 10 60 7A 00 02 04 0D 40 00 03 9F 8F"));
    }

    fn hex(s: &str) -> Vec<u8> {
        s.split_whitespace()
            .map(|b| u8::from_str_radix(b, 16).unwrap())
            .collect()
    }

    #[test]
    fn a_refused_value_answers_the_masters_exception_code() {
        let mut b = Bench::new();
        let mut port = Slave::new();
        // SPEC §5.2 step 8: mode 2 → 3; step 4: 0x6090 → 11; step 7: RO → 5.
        let cases = [
            (Pdu::write_single(0x6060, 2), 3),
            (Pdu::write_single(0x6090, 3), 11),
            (Pdu::write_single(0x6041, 1), 5),
            (Pdu::read(0x6040, 1), 7),
            (Pdu::write_single(0x0064 + 51, 300), 3),
        ];
        for (pdu, code) in &cases {
            assert_eq!(
                transact(&mut b, &mut port, pdu, 0).0,
                Answer::Exception(*code),
                "{pdu:?}"
            );
        }
        // PA55 = 1: the standard profile maps 11 → 2 and 5 → 2 (SPEC §5.2).
        let ok = transact(&mut b, &mut port, &Pdu::write_single(0x0064 + 55, 1), 0).0;
        assert!(matches!(ok, Answer::Ok(_)), "{ok:?}");
        let a = transact(&mut b, &mut port, &Pdu::write_single(0x6090, 3), 0).0;
        assert_eq!(a, Answer::Exception(2));
        let a = transact(&mut b, &mut port, &Pdu::write_single(0x6041, 1), 0).0;
        assert_eq!(a, Answer::Exception(2));
        // The drive still refused nothing it should have stored.
        assert_eq!(b.device.od().mode(), 0);
        assert_eq!(b.device.params().address(), 1);
    }

    #[test]
    fn accepted_writes_reach_the_drive_and_reads_come_back() {
        let mut b = Bench::new();
        let mut port = Slave::new();
        let w = Pdu::write_multiple(0x607A, &Pdu::words32(-1234i32 as u32, false));
        assert!(matches!(
            transact(&mut b, &mut port, &w, 0).0,
            Answer::Ok(_)
        ));
        assert_eq!(b.device.od().target_position(), -1234);
        let Answer::Ok(pdu) = transact(&mut b, &mut port, &Pdu::read(0x607A, 2), 0).0 else {
            panic!("read refused");
        };
        assert_eq!(read_words(&pdu), Pdu::words32(-1234i32 as u32, false));
        // The controlword acts as from the bus: 0x06, 0x07, 0x0F → enabled.
        for cw in [0x06, 0x07, 0x0F] {
            let a = transact(&mut b, &mut port, &Pdu::write_single(0x6040, cw), 0).0;
            assert!(matches!(a, Answer::Ok(_)), "{cw:#x}: {a:?}");
        }
        assert_eq!(b.device.drive().statusword() & 0x6F, 0x27);
        // Each request is followed by a control call, as on the bus path.
        assert_eq!(b.controls, 5);
    }

    #[test]
    fn the_page_counts_on_its_own_port_not_on_the_bus() {
        let mut b = Bench::new();
        let mut port = Slave::new();
        let _ = transact(&mut b, &mut port, &Pdu::read(0x6041, 1), 0);
        let _ = transact(&mut b, &mut port, &Pdu::write_single(0x6060, 2), 0);
        assert_eq!(b.device.slave().counters().bus_messages(), 0);
        assert_eq!(b.device.slave().counters().exceptions(), 0);
        assert_eq!(port.counters().bus_messages(), 2);
        assert_eq!(port.counters().slave_messages(), 2);
        assert_eq!(port.counters().exceptions(), 1);
    }

    #[test]
    fn a_busy_drive_refuses_the_page_as_it_refuses_the_bus() {
        let mut b = Bench::new();
        let mut port = Slave::new();
        b.device.set_storage_busy(true);
        let a = transact(&mut b, &mut port, &Pdu::write_single(0x6060, 1), 0).0;
        assert_eq!(a, Answer::Exception(6));
        assert_eq!(b.device.od().mode(), 0);
    }

    #[test]
    fn an_ee_save_runs_on_the_flash_and_answers_the_0x10_reply() {
        let mut b = Bench::new();
        let mut port = Slave::new();
        let w = Pdu::write_single(0x0064 + 12, 1500);
        assert!(matches!(
            transact(&mut b, &mut port, &w, 0).0,
            Answer::Ok(_)
        ));
        let save = Pdu::write_multiple(EE_REGISTER, &[1]);
        assert_eq!(
            transact(&mut b, &mut port, &save, 0).0,
            Answer::Ok(vec![0x10, 0x00, 0x3A, 0x00, 0x01])
        );
        assert!(!b.device.busy());
        // Saved: a fresh drive on the same flash boots with PA12 = 1500.
        let mut d = Device::new(Identity::new("test"));
        d.apply_boot(&b.store.boot());
        assert_eq!(d.params().max_speed_rpm(), 1500);
    }

    #[test]
    fn replies_that_do_not_answer_the_request_are_not_taken_for_answers() {
        let req = Pdu::read(0x6041, 1);
        assert_eq!(parse_reply(1, &req, &[]), Answer::Silent);
        let mut ok = Pdu(vec![0x03, 0x02, 0x00, 0x37]).frame(1);
        assert_eq!(
            parse_reply(1, &req, &ok),
            Answer::Ok(vec![0x03, 0x02, 0x00, 0x37])
        );
        assert!(matches!(parse_reply(2, &req, &ok), Answer::Malformed(_)));
        ok[3] ^= 1;
        assert!(matches!(parse_reply(1, &req, &ok), Answer::Malformed(_)));
        let other = Pdu(vec![0x06, 0x60, 0x40, 0x00, 0x01]).frame(1);
        assert!(matches!(parse_reply(1, &req, &other), Answer::Malformed(_)));
        let exc = Pdu(vec![0x83, 0x07]).frame(1);
        assert_eq!(parse_reply(1, &req, &exc), Answer::Exception(7));
    }
}
