//! What the page shows of a drive, as JSON: status, counters, the last
//! exceptions, the object dictionary and the PA set with their values.
//! Built on the drive loop from the drive as it is (reading only).

use std::fmt::Write;

use modbus_drive::dictionary::{pa_entries, position, DataType, DriveLayer, Entry, TABLE};
use modbus_drive::motion::Switches;
use modbus_drive::slave::{Counters, Slave};
use modbus_drive::Device;

use super::exceptions::ExceptionLog;
use super::force::{Forced, Switch};

/// Following error actual value (SPEC §8.8), shown once the table has it.
pub const FOLLOWING_ERROR: u16 = 0x60F4;

/// Everything of one drive the page shows.
pub struct View<'a> {
    pub device: &'a Device,
    pub port: &'a Slave,
    pub axis_switches: Switches,
    pub forced: Forced,
    pub exceptions: &'a ExceptionLog,
}

/// The value of a numeric dictionary entry, read as a master would see it
/// (signed types sign-extended); `None` for strings.
pub fn entry_value(device: &Device, index: u16) -> Option<i64> {
    let e = &TABLE[position(index)?];
    let raw = e.object().read_raw(device.od(), device.drive());
    (e.data_type() != DataType::Str).then(|| e.data_type().value(raw))
}

/// JSON string literal.
pub fn quote(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if (c as u32) < 0x20 => {
                let _ = write!(out, "\\u{:04x}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

fn counters(c: &Counters) -> String {
    format!(
        "{{\"bus_messages\":{},\"bus_errors\":{},\"exceptions\":{},\"slave_messages\":{},\
         \"no_response\":{},\"busy\":{},\"overruns\":{}}}",
        c.bus_messages,
        c.bus_errors,
        c.exceptions,
        c.slave_messages,
        c.no_response,
        c.busy,
        c.overruns
    )
}

fn opt_bool(v: Option<bool>) -> &'static str {
    match v {
        None => "null",
        Some(true) => "true",
        Some(false) => "false",
    }
}

/// The page's JSON for one drive.
pub fn drive_json(v: &View<'_>) -> String {
    let d = v.device;
    let seen = v.forced.apply(v.axis_switches);
    let mut s = String::with_capacity(8 * 1024);
    let _ = write!(
        s,
        "{{\"address\":{},\"state\":{},\"statusword\":{},\"error_register\":{},\"mode\":{},\
         \"position\":{},\"velocity\":{},\"following_error\":{},\"listen_only\":{},\"busy\":{},",
        d.address(),
        quote(&format!("{:?}", d.drive().state())),
        d.drive().statusword(),
        d.drive().error_register(),
        d.drive().mode_display(),
        d.drive().actual_position(),
        d.drive().actual_velocity_rpm(),
        entry_value(d, FOLLOWING_ERROR).map_or("null".into(), |v| v.to_string()),
        d.slave().listen_only(),
        d.busy(),
    );
    let _ = write!(
        s,
        "\"switches\":{{\"cw\":{},\"ccw\":{},\"home\":{}}},\
         \"axis_switches\":{{\"cw\":{},\"ccw\":{},\"home\":{}}},\
         \"forced\":{{\"cw\":{},\"ccw\":{},\"home\":{}}},",
        seen.cw_limit,
        seen.ccw_limit,
        seen.home,
        v.axis_switches.cw_limit,
        v.axis_switches.ccw_limit,
        v.axis_switches.home,
        opt_bool(v.forced.get(Switch::CwLimit)),
        opt_bool(v.forced.get(Switch::CcwLimit)),
        opt_bool(v.forced.get(Switch::Home)),
    );
    let _ = write!(
        s,
        "\"bus_counters\":{},\"page_counters\":{},\"exceptions\":[",
        counters(d.slave().counters()),
        counters(v.port.counters())
    );
    for (i, r) in v.exceptions.iter().enumerate() {
        let _ = write!(
            s,
            "{}{{\"seq\":{},\"t\":{:.3},\"port\":{},\"function\":{},\"code\":{},\"answered\":{}}}",
            if i > 0 { "," } else { "" },
            r.seq,
            r.time_s,
            quote(&r.port),
            r.function,
            r.code,
            r.answered
        );
    }
    s.push_str("],\"od\":[");
    for (i, e) in TABLE.iter().enumerate() {
        let value = match e.object().string(d.identity()) {
            Some(text) => quote(text),
            None if e.access().readable() => entry_value(d, e.index()).unwrap_or(0).to_string(),
            // A master reads exception 7; the page shows the last write.
            None => format!("{{\"written\":{}}}", written(e, d)),
        };
        let _ = write!(
            s,
            "{}{{\"index\":{},\"name\":{},\"access\":\"{}\",\"type\":\"{:?}\",\
             \"unit\":{},\"range\":{},\"value\":{}}}",
            if i > 0 { "," } else { "" },
            e.index(),
            quote(&format!("{:?}", e.object())),
            e.access().label(),
            e.data_type(),
            quote(e.unit()),
            // what a write may carry; a read-only entry takes none
            quote(&if e.access().writable() {
                e.range().to_string()
            } else {
                "—".to_string()
            }),
            value
        );
    }
    s.push_str("],\"pa\":[");
    for p in pa_entries() {
        let (n, def) = (p.number(), p.def());
        let _ = write!(
            s,
            "{}{{\"n\":{n},\"name\":{},\"unit\":{},\"min\":{},\"max\":{},\"default\":{},\
             \"access\":\"{}\",\"value\":{}}}",
            if n > 0 { "," } else { "" },
            quote(p.name()),
            quote(p.unit()),
            def.min(),
            def.max(),
            def.default(),
            if def.read_only() { "RO" } else { "RW" },
            d.params().get(n)
        );
    }
    s.push_str("]}");
    s
}

/// The last value written to a write-only entry (what the drive holds).
fn written(e: &Entry, d: &Device) -> i64 {
    e.data_type().value(e.object().read_raw(d.od(), d.drive()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use modbus_drive::device::Identity;
    use modbus_drive::params::PA_COUNT;

    #[test]
    fn strings_are_escaped() {
        assert_eq!(quote("a\"b\\c\n"), "\"a\\\"b\\\\c\\u000a\"");
    }

    #[test]
    fn the_view_lists_every_entry_and_parameter_with_its_value() {
        let mut d = Device::new(Identity::new("t"));
        d.configure(|pa, od| {
            od.target_position = -7;
            pa.set_unchecked(12, 1234);
        });
        let port = Slave::new();
        let log = ExceptionLog::new();
        let mut forced = Forced::default();
        forced.set(Switch::Home, Some(true));
        let json = drive_json(&View {
            device: &d,
            port: &port,
            axis_switches: Switches::default(),
            forced,
            exceptions: &log,
        });
        assert_eq!(json.matches("\"index\":").count(), TABLE.len());
        assert_eq!(json.matches("\"n\":").count(), PA_COUNT);
        assert!(json.contains("\"name\":\"TargetPosition\""));
        assert!(json.contains("\"value\":-7"));
        assert!(json.contains("\"n\":12,\"name\":\"maximum speed\""));
        assert!(json.contains("\"value\":1234"));
        assert!(json.contains("\"switches\":{\"cw\":false,\"ccw\":false,\"home\":true}"));
        assert!(json.contains("\"forced\":{\"cw\":null,\"ccw\":null,\"home\":true}"));
        assert!(json.contains("\"value\":\"modbus-drive\""));
        assert_eq!(
            json.contains("\"following_error\":null"),
            position(FOLLOWING_ERROR).is_none()
        );
    }
}
