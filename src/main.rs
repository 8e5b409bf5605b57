//! The program: firmware on `target_os = "none"`, the virtual drive on a host.
fn main() {
    eprintln!("modbus-drive: the virtual drive is not built yet (issue 4)");
    std::process::exit(2);
}
