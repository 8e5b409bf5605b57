//! What the page shows of a drive, as JSON: status, counters, the last
//! exceptions, the object dictionary and the PA set with their values.
//! Built on the drive loop from the drive as it is (reading only).

use std::fmt::Write;

use modbus_drive::dictionary::{DriveLayer, Object};
use modbus_drive::motion::Switches;
use modbus_drive::slave::{Counters, Slave};
use modbus_drive::Device;

use super::exceptions::ExceptionLog;
use super::force::{Forced, Switch};
use crate::virtual_drive::registers::{od_meta, pa_meta, position, DataType, PA, TABLE};

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
    Some(match e.data_type() {
        DataType::U16 => i64::from(raw as u16),
        DataType::I16 => i64::from(raw as u16 as i16),
        DataType::U32 => i64::from(raw),
        DataType::I32 => i64::from(raw as i32),
        DataType::Str => return None,
    })
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
        c.bus_messages(),
        c.bus_errors(),
        c.exceptions(),
        c.slave_messages(),
        c.no_response(),
        c.busy(),
        c.overruns()
    )
}

fn opt_bool(v: Option<bool>) -> &'static str {
    match v {
        None => "null",
        Some(true) => "true",
        Some(false) => "false",
    }
}

/// What a table cell of the dictionary shows.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum OdValue {
    Number(i64),
    Text(String),
    /// A write-only entry: the last value written (a master reads
    /// exception 7 there).
    Written(i64),
}

/// The values of one drive the page shows, however they were obtained: read
/// from the drive in-process ([`drive_json`]) or by Modbus requests (the
/// commissioning master). `None` where that back end has no such value.
pub struct Snapshot<'a> {
    pub address: u8,
    /// Power state (SPEC §8.1) as its variant's name.
    pub state: String,
    pub statusword: u16,
    pub error_register: u16,
    pub mode: i64,
    pub position: i64,
    pub velocity: i64,
    pub following_error: Option<i64>,
    pub listen_only: bool,
    pub busy: bool,
    pub switches: Switches,
    /// The simulated axis's own switches and the page's forcing.
    pub axis: Option<(Switches, Forced)>,
    pub bus_counters: Option<Counters>,
    pub page_counters: Option<Counters>,
    pub exceptions: &'a ExceptionLog,
    /// Per [`TABLE`] entry, `None` where unknown.
    pub od: Vec<Option<OdValue>>,
    /// Per PA, `None` where unknown.
    pub pa: Vec<Option<u16>>,
    /// The link to a remote drive, as a JSON object.
    pub link: Option<String>,
}

/// The page's JSON for one drive run in-process.
pub fn drive_json(v: &View<'_>) -> String {
    let d = v.device;
    let od = TABLE
        .iter()
        .map(|e| {
            Some(match e.object().string(d.identity()) {
                Some(text) => OdValue::Text(text.into()),
                None if e.access().readable() => {
                    OdValue::Number(entry_value(d, e.index()).unwrap_or(0))
                }
                None => OdValue::Written(written(e.object(), d)),
            })
        })
        .collect();
    snapshot_json(&Snapshot {
        address: d.address(),
        state: format!("{:?}", d.drive().state()),
        statusword: d.drive().statusword(),
        error_register: d.drive().error_register(),
        mode: i64::from(d.drive().mode_display()),
        position: i64::from(d.drive().actual_position()),
        velocity: i64::from(d.drive().actual_velocity_rpm()),
        following_error: entry_value(d, FOLLOWING_ERROR),
        listen_only: d.slave().listen_only(),
        busy: d.busy(),
        switches: v.forced.apply(v.axis_switches),
        axis: Some((v.axis_switches, v.forced)),
        bus_counters: Some(d.slave().counters().clone()),
        page_counters: Some(v.port.counters().clone()),
        exceptions: v.exceptions,
        od,
        pa: (0..PA.len()).map(|n| Some(d.params().get(n))).collect(),
        link: None,
    })
}

fn opt<T>(v: Option<T>, f: impl Fn(T) -> String) -> String {
    v.map_or_else(|| "null".into(), f)
}

fn switches_json(s: Switches) -> String {
    format!(
        "{{\"cw\":{},\"ccw\":{},\"home\":{}}}",
        s.cw_limit(),
        s.ccw_limit(),
        s.home()
    )
}

/// The page's JSON for one drive.
pub fn snapshot_json(v: &Snapshot<'_>) -> String {
    let mut s = String::with_capacity(8 * 1024);
    let _ = write!(
        s,
        "{{\"address\":{},\"state\":{},\"statusword\":{},\"error_register\":{},\"mode\":{},\
         \"position\":{},\"velocity\":{},\"following_error\":{},\"listen_only\":{},\"busy\":{},",
        v.address,
        quote(&v.state),
        v.statusword,
        v.error_register,
        v.mode,
        v.position,
        v.velocity,
        opt(v.following_error, |f| f.to_string()),
        v.listen_only,
        v.busy,
    );
    let _ = write!(
        s,
        "\"switches\":{},\"axis_switches\":{},\"forced\":{},",
        switches_json(v.switches),
        opt(v.axis, |(a, _)| switches_json(a)),
        opt(v.axis, |(_, f)| format!(
            "{{\"cw\":{},\"ccw\":{},\"home\":{}}}",
            opt_bool(f.get(Switch::CwLimit)),
            opt_bool(f.get(Switch::CcwLimit)),
            opt_bool(f.get(Switch::Home)),
        )),
    );
    let _ = write!(
        s,
        "\"link\":{},\"bus_counters\":{},\"page_counters\":{},\"exceptions\":[",
        v.link.as_deref().unwrap_or("null"),
        opt(v.bus_counters.as_ref(), counters),
        opt(v.page_counters.as_ref(), counters),
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
        let (unit, range) = od_meta(e.index());
        let value = match v.od.get(i).and_then(Option::as_ref) {
            Some(OdValue::Number(n)) => n.to_string(),
            Some(OdValue::Text(t)) => quote(t),
            Some(OdValue::Written(w)) => format!("{{\"written\":{w}}}"),
            None => "null".into(),
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
            quote(unit),
            quote(&range),
            value
        );
    }
    s.push_str("],\"pa\":[");
    for (n, def) in PA.iter().enumerate() {
        let (name, unit) = pa_meta(n);
        let _ = write!(
            s,
            "{}{{\"n\":{n},\"name\":{},\"unit\":{},\"min\":{},\"max\":{},\"default\":{},\
             \"access\":\"{}\",\"value\":{}}}",
            if n > 0 { "," } else { "" },
            quote(name),
            quote(unit),
            def.min(),
            def.max(),
            def.default(),
            if def.read_only() { "RO" } else { "RW" },
            opt(v.pa.get(n).copied().flatten(), |x| x.to_string())
        );
    }
    s.push_str("]}");
    s
}

/// The last value written to a write-only entry (what the drive holds).
fn written(object: Object, d: &Device) -> i64 {
    let raw = object.read_raw(d.od(), d.drive());
    match object {
        Object::ModeOfOperation => i64::from(raw as u16 as i16),
        _ => i64::from(raw),
    }
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
            od.set_target_position(-7);
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
