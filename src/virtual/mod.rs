//! The virtual drive (issue 4): not built yet.
use std::process::ExitCode;

pub fn main() -> ExitCode {
    eprintln!("modbus-drive: the virtual drive is not built yet (issue 4)");
    ExitCode::from(2)
}
