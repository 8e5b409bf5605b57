//! docs/generated/registers.md is rendered from the register tables
//! (`dictionary::TABLE`, `PA`, `DP_ITEMS`) and must match them: this test
//! fails when the file is stale. `UPDATE_GENERATED=1 cargo test --test
//! generated_registers` rewrites it.

use std::fmt::Write;

use modbus_drive::dictionary::{
    pa_entries, DataType, Range, DP_BASE, DP_ITEMS, PA_BASE, SAVED_COUNT, TABLE,
};
use modbus_drive::params::{RECORD_LEN, RECORD_VERSION};

const PATH: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/docs/generated/registers.md");

fn cell(s: &str) -> &str {
    if s.is_empty() {
        "—"
    } else {
        s
    }
}

fn render() -> String {
    let mut s = String::new();
    s.push_str(
        "# Register tables (generated)\n\n\
         Rendered from the register tables of the code (`src/dictionary/table.rs`, \
         `src/dictionary/pa.rs`, `src/dictionary/monitor.rs`) by \
         `tests/generated_registers.rs`, which fails when this file is stale; \
         `UPDATE_GENERATED=1 cargo test --test generated_registers` rewrites it. \
         Do not edit. Behaviour: [../protocol.md](../protocol.md), \
         [../parameters.md](../parameters.md).\n\n",
    );
    let _ = write!(
        s,
        "## Object dictionary (SPEC §5)\n\n\
         In table order: a request walks this order, and may cover several \
         entries (SPEC §5.2). A write outside the range gets exception 3. \
         \"slot\": place in the saved record (record version {RECORD_VERSION}, \
         {SAVED_COUNT} entries, {RECORD_LEN} bytes; `src/params/record.rs`).\n\n\
         | # | index | name | access | type | words | range | default | unit | slot |\n\
         |---:|---|---|---|---|---:|---|---|---|---:|\n"
    );
    for (i, e) in TABLE.iter().enumerate() {
        let default = match e.data_type() {
            DataType::Str => "identity".to_string(),
            DataType::U32 if e.default() == -1 => "0xFFFFFFFF".to_string(),
            _ => e.default().to_string(),
        };
        let range = match (e.access().writable(), e.range()) {
            (false, _) => "—".to_string(),
            (true, r) => r.to_string(),
        };
        let slot = e.record_slot().map_or("—".to_string(), |s| s.to_string());
        let _ = writeln!(
            s,
            "| {} | 0x{:04X} | {} | {} | {:?} | {} | {} | {} | {} | {} |",
            i + 1,
            e.index(),
            e.name(),
            e.access().label(),
            e.data_type(),
            e.words(),
            range,
            default,
            cell(e.unit()),
            slot
        );
    }
    let _ = write!(
        s,
        "\n## PA parameters (SPEC §7, at 0x{PA_BASE:04X} + n)\n\n\
         16-bit, saved (every PA is in the record). A write outside the range \
         gets exception 3, a write of a read-only one 5. A reserved PA stores \
         any value and has no effect.\n\n\
         | PA | address | name | access | range | default | unit |\n\
         |---:|---|---|---|---|---:|---|\n"
    );
    for p in pa_entries().filter(|p| p.assigned()) {
        let (n, d) = (p.number(), p.def());
        let range = match d.range() {
            Range::Any => "0..=65535".to_string(),
            r => r.to_string(),
        };
        let _ = writeln!(
            s,
            "| {n} | 0x{:04X} | {} | {} | {} | {} | {} |",
            p.address(),
            p.name(),
            if d.read_only() { "RO" } else { "RW" },
            range,
            d.default(),
            cell(p.unit())
        );
    }
    let reserved: Vec<String> = pa_entries()
        .filter(|p| !p.assigned())
        .map(|p| p.number().to_string())
        .collect();
    let _ = writeln!(
        s,
        "\nReserved (RW, 0..=65535, default 0): PA{}.",
        reserved.join(", ")
    );
    s.push_str(
        "\n## DP monitor (SPEC §9, read-only)\n\n\
         | address | item | what | unit |\n\
         |---|---|---|---|\n",
    );
    for (i, d) in DP_ITEMS.iter().enumerate() {
        let _ = writeln!(
            s,
            "| 0x{:04X} | {} | {} | {} |",
            DP_BASE + i as u16,
            d.name(),
            d.what(),
            cell(d.unit())
        );
    }
    s
}

#[test]
fn the_generated_register_tables_are_up_to_date() {
    let want = render();
    if std::env::var_os("UPDATE_GENERATED").is_some() {
        std::fs::write(PATH, &want).expect("write docs/generated/registers.md");
        return;
    }
    let have = std::fs::read_to_string(PATH).unwrap_or_default();
    assert!(
        have == want,
        "docs/generated/registers.md is stale: run \
         `UPDATE_GENERATED=1 cargo test --test generated_registers`"
    );
}
