//! The master's own count of its requests and what came back, shown in
//! the page's "page" counter column beside the drive's §6 counters: the
//! drive counts what it heard, the master what it sent and got, so a
//! difference between the two columns points at the line.

use modbus_drive::slave::Counters;

use crate::virtual_drive::web::Answer;

/// Exception code 6, "slave device busy".
const BUSY: u8 = 6;

/// Requests sent and their outcomes, each wrapping at 65536 as the drive's
/// §6 counters do.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Tally {
    sent: u16,
    replies: u16,
    timeouts: u16,
    exceptions: u16,
    busy: u16,
    crc_errors: u16,
}

impl Tally {
    /// One request that left on the link and what came back: `reply` as
    /// received (empty: none in time), `answer` as parsed; `has_crc` says
    /// whether the link's frames carry one (RTU yes, Modbus TCP no).
    pub fn count(&mut self, reply: &[u8], answer: &Answer, has_crc: bool) {
        let add = |c: &mut u16| *c = c.wrapping_add(1);
        add(&mut self.sent);
        if reply.is_empty() {
            add(&mut self.timeouts);
            return;
        }
        if has_crc && reply.len() >= 2 && modbus_drive::rtu::crc16(reply) != 0 {
            add(&mut self.crc_errors);
        }
        match answer {
            Answer::Ok(_) => add(&mut self.replies),
            Answer::Exception(code) => {
                add(&mut self.replies);
                add(&mut self.exceptions);
                if *code == BUSY {
                    add(&mut self.busy);
                }
            }
            Answer::Silent | Answer::Malformed(_) => {}
        }
    }

    /// As the rows of the §6 table: bus messages ↔ requests sent, bus
    /// errors ↔ replies with a wrong CRC, exceptions ↔ exception replies,
    /// slave messages ↔ replies that answer their request, no response ↔
    /// requests without a reply in time, busy ↔ exception 6 replies;
    /// overruns the master cannot see (0).
    pub fn as_counters(&self) -> Counters {
        Counters::from_reads([
            self.sent,
            self.crc_errors,
            self.exceptions,
            self.replies,
            self.timeouts,
            self.busy,
            0,
        ])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::virtual_drive::web::Pdu;

    #[test]
    fn each_outcome_lands_in_its_row() {
        let frame = |pdu: &[u8]| Pdu(pdu.to_vec()).frame(1);
        let mut t = Tally::default();
        t.count(&[], &Answer::Silent, true);
        t.count(&frame(&[3, 2, 0, 7]), &Answer::Ok(vec![3, 2, 0, 7]), true);
        t.count(&frame(&[0x83, 2]), &Answer::Exception(2), true);
        t.count(&frame(&[0x83, BUSY]), &Answer::Exception(BUSY), true);
        // a reply whose CRC is wrong: seen, not a reply to the request
        let mut bad = frame(&[3, 2, 0, 7]);
        bad[3] ^= 1;
        t.count(&bad, &Answer::Malformed(bad.clone()), true);
        // Modbus TCP frames carry no CRC
        t.count(
            &[0, 1, 0, 0, 0, 3, 1, 3, 0],
            &Answer::Malformed(vec![]),
            false,
        );
        let c = t.as_counters();
        assert_eq!(
            (c.bus_messages(), c.slave_messages(), c.no_response()),
            (6, 3, 1)
        );
        assert_eq!(
            (c.exceptions(), c.busy(), c.bus_errors(), c.overruns()),
            (2, 1, 1, 0)
        );
    }
}
