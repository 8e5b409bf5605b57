//! Links the bench with its own minimal script (bench.ld): no cortex-m-rt,
//! so nothing from the firmware's memory.x or link.x can reach it.
fn main() {
    let dir = std::env::var("CARGO_MANIFEST_DIR").unwrap_or_default();
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        println!("cargo:rustc-link-arg-bins=-T{dir}/bench.ld");
    }
    println!("cargo:rerun-if-changed=bench.ld");
}
