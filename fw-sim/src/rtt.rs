//! The firmware's defmt log: bytes of RTT up-buffer 0 (the `_SEGGER_RTT`
//! control block in emulated SRAM, written by defmt-rtt) decoded with the
//! ELF's defmt table and printed on stderr as `probe-rs run` prints them.

use defmt_decoder::{DecodeError, Locations, StreamDecoder, Table};

pub struct Rtt {
    cb: u32,
    decoder: Box<dyn StreamDecoder + Send + Sync>,
    table: &'static Table,
    locations: Option<Locations>,
}

impl Rtt {
    pub fn new(elf: &[u8], cb: u32) -> Option<Self> {
        let table: &'static Table = Box::leak(Box::new(Table::parse(elf).ok()??));
        let locations = table.get_locations(elf).ok();
        Some(Self {
            cb,
            decoder: table.new_stream_decoder(),
            table,
            locations,
        })
    }

    /// Reads what the firmware wrote since the last call (`read` reads
    /// emulated memory) and prints the decoded frames; moves RdOff.
    pub fn poll(
        &mut self,
        read: &mut dyn FnMut(u32, usize) -> Option<Vec<u8>>,
        write_rd: &mut dyn FnMut(u32, u32),
    ) {
        let up = self.cb + 24;
        let Some(h) = read(up, 24) else { return };
        let w = |i: usize| u32::from_le_bytes([h[i], h[i + 1], h[i + 2], h[i + 3]]);
        let (buf, size, wr, rd) = (w(4), w(8), w(12), w(16));
        if buf == 0 || size == 0 || wr == rd || wr >= size || rd >= size {
            return;
        }
        let mut bytes = Vec::new();
        if wr > rd {
            bytes.extend(read(buf + rd, (wr - rd) as usize).unwrap_or_default());
        } else {
            bytes.extend(read(buf + rd, (size - rd) as usize).unwrap_or_default());
            bytes.extend(read(buf, wr as usize).unwrap_or_default());
        }
        write_rd(up + 16, wr);
        self.decoder.received(&bytes);
        loop {
            match self.decoder.decode() {
                Ok(frame) => {
                    let _ = self.table;
                    eprintln!("{}", frame.display(false));
                    if let Some(loc) = self.locations.as_ref().and_then(|l| l.get(&frame.index())) {
                        eprintln!("└─ {} @ {}:{}", loc.module, loc.file.display(), loc.line);
                    }
                }
                Err(DecodeError::UnexpectedEof) => break,
                Err(DecodeError::Malformed) => {
                    eprintln!("(defmt: malformed frame in the RTT buffer)");
                    break;
                }
            }
        }
    }
}
