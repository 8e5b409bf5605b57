//! The parameter file of `params save` / `params restore`: PA0..PA59 by
//! name, with the firmware version they belong to and when they were read.
//! TOML (`.toml`, the default) or JSON (`.json`); both flat, both written
//! and read here (a subset: integers and strings, one `pa` table).
//!
//! ```toml
//! firmware = 7060
//! date = "2026-11-27T03:00:00Z"
//! drive = "address 1, /dev/ttyUSB0 at 115200 8N1"
//!
//! [pa]
//! PA10 = 10000  # steps per revolution (steps)
//! ```
//!
//! Values are read as plain integers whatever their size, so that a value
//! out of a PA's range is refused with the PA's name rather than as a
//! syntax error.

use std::collections::BTreeMap;
use std::fmt::Write;

use crate::virtual_drive::registers::{pa_meta, PA_COUNT};
// a TOML basic string escapes as a JSON string does
use crate::virtual_drive::web::quote;

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ParamFile {
    /// PA2 of the drive the set was read from.
    pub firmware: i64,
    /// UTC, ISO 8601.
    pub date: String,
    /// Where it was read (for the reader).
    pub drive: String,
    /// PA number → value, as in the file.
    pub pa: BTreeMap<usize, i64>,
}

fn name_comment(n: usize) -> String {
    let (name, unit) = pa_meta(n);
    if unit.is_empty() {
        name.into()
    } else {
        format!("{name} ({unit})")
    }
}

impl ParamFile {
    pub fn to_toml(&self) -> String {
        let mut s = String::from(
            "# modbus-drive parameter set, PA0..PA59 (SPEC §7).\n\
             # Restore: modbus-drive params restore --serial PORT FILE [--yes]\n",
        );
        let _ = writeln!(s, "firmware = {}", self.firmware);
        let _ = writeln!(s, "date = {}", quote(&self.date));
        let _ = writeln!(s, "drive = {}", quote(&self.drive));
        s.push_str("\n[pa]\n");
        for (n, v) in &self.pa {
            let _ = writeln!(s, "{:<12} # {}", format!("PA{n} = {v}"), name_comment(*n));
        }
        s
    }

    pub fn to_json(&self) -> String {
        let mut s = String::from("{\n");
        let _ = writeln!(s, "  \"firmware\": {},", self.firmware);
        let _ = writeln!(s, "  \"date\": {},", quote(&self.date));
        let _ = writeln!(s, "  \"drive\": {},", quote(&self.drive));
        let list = |f: &dyn Fn(usize, i64) -> String| {
            self.pa
                .iter()
                .map(|(n, v)| format!("    \"PA{n}\": {}", f(*n, *v)))
                .collect::<Vec<_>>()
                .join(",\n")
        };
        let _ = writeln!(s, "  \"pa\": {{\n{}\n  }},", list(&|_, v| v.to_string()));
        let _ = writeln!(
            s,
            "  \"names\": {{\n{}\n  }}",
            list(&|n, _| quote(&name_comment(n)))
        );
        s.push_str("}\n");
        s
    }

    /// Reads either format (JSON when it starts with `{`).
    pub fn parse(text: &str) -> Result<Self, String> {
        let pairs = if text.trim_start().starts_with('{') {
            json_pairs(text)?
        } else {
            toml_pairs(text)?
        };
        let mut f = ParamFile {
            firmware: -1,
            date: String::new(),
            drive: String::new(),
            pa: BTreeMap::new(),
        };
        for (table, key, value) in pairs {
            match (table.as_str(), key.as_str(), value) {
                ("", "firmware", Value::Int(v)) => f.firmware = v,
                ("", "date", Value::Str(v)) => f.date = v,
                ("", "drive", Value::Str(v)) => f.drive = v,
                ("names", _, _) => {}
                ("pa", k, Value::Int(v)) => {
                    let n = k
                        .strip_prefix("PA")
                        .and_then(|n| n.parse::<usize>().ok())
                        .filter(|&n| n < PA_COUNT)
                        .ok_or(format!("{k}: not a parameter (PA0..PA59)"))?;
                    if f.pa.insert(n, v).is_some() {
                        return Err(format!("PA{n} given twice"));
                    }
                }
                (t, k, v) => {
                    let at = if t.is_empty() {
                        k.to_string()
                    } else {
                        format!("{t}.{k}")
                    };
                    return Err(format!("{at} = {v:?}: not a key of a parameter file"));
                }
            }
        }
        if f.firmware < 0 {
            return Err("no firmware version (firmware = …) in the file".into());
        }
        Ok(f)
    }
}

#[derive(Clone, Debug, PartialEq, Eq)]
enum Value {
    Int(i64),
    Str(String),
}

fn parse_int(v: &str) -> Option<i64> {
    let v = v.trim();
    match v.strip_prefix("0x") {
        Some(h) => i64::from_str_radix(h, 16).ok(),
        None => v.parse().ok(),
    }
}

/// `(table, key, value)` of each `key = value` line.
fn toml_pairs(text: &str) -> Result<Vec<(String, String, Value)>, String> {
    let mut table = String::new();
    let mut out = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        let at = |why: &str| format!("line {}: {why}: {raw}", i + 1);
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        if let Some(t) = line.strip_prefix('[') {
            table = t
                .strip_suffix(']')
                .ok_or_else(|| at("a table header ends with ]"))?
                .trim()
                .to_string();
            continue;
        }
        let (key, rest) = line.split_once('=').ok_or_else(|| at("not key = value"))?;
        let rest = rest.trim();
        let value = if let Some(s) = rest.strip_prefix('"') {
            Value::Str(toml_string(s).ok_or_else(|| at("a string ends with \""))?)
        } else {
            let v = rest.split('#').next().unwrap_or("");
            Value::Int(parse_int(v).ok_or_else(|| at("not an integer"))?)
        };
        out.push((table.clone(), key.trim().to_string(), value));
    }
    Ok(out)
}

/// A basic string after its opening quote, escapes resolved; `None` when
/// it does not end on this line.
fn toml_string(s: &str) -> Option<String> {
    let mut out = String::new();
    let mut chars = s.chars();
    while let Some(c) = chars.next() {
        match c {
            '"' => return Some(out),
            '\\' => match chars.next()? {
                'n' => out.push('\n'),
                't' => out.push('\t'),
                'u' => {
                    let h: String = chars.by_ref().take(4).collect();
                    out.push(char::from_u32(u32::from_str_radix(&h, 16).ok()?)?);
                }
                other => out.push(other),
            },
            c => out.push(c),
        }
    }
    None
}

/// The same pairs from the JSON layout [`ParamFile::to_json`] writes: an
/// object of integers, strings and objects of those.
fn json_pairs(text: &str) -> Result<Vec<(String, String, Value)>, String> {
    let mut p = Json {
        b: text.as_bytes(),
        i: 0,
    };
    let mut out = Vec::new();
    p.object("", &mut out, 0)?;
    p.ws();
    if p.i != p.b.len() {
        return Err(format!("JSON: text after the object at byte {}", p.i));
    }
    Ok(out)
}

struct Json<'a> {
    b: &'a [u8],
    i: usize,
}

impl Json<'_> {
    fn ws(&mut self) {
        while self.b.get(self.i).is_some_and(|c| c.is_ascii_whitespace()) {
            self.i += 1;
        }
    }

    fn expect(&mut self, c: u8) -> Result<(), String> {
        self.ws();
        if self.b.get(self.i) == Some(&c) {
            self.i += 1;
            Ok(())
        } else {
            Err(format!("JSON: '{}' expected at byte {}", c as char, self.i))
        }
    }

    fn string(&mut self) -> Result<String, String> {
        self.expect(b'"')?;
        let mut s = Vec::new();
        loop {
            let c = *self.b.get(self.i).ok_or("JSON: unterminated string")?;
            self.i += 1;
            match c {
                b'"' => break,
                b'\\' => {
                    let e = *self.b.get(self.i).ok_or("JSON: unterminated string")?;
                    self.i += 1;
                    match e {
                        b'u' => {
                            let h = self.b.get(self.i..self.i + 4).ok_or("JSON: bad \\u")?;
                            let code =
                                u32::from_str_radix(std::str::from_utf8(h).unwrap_or(""), 16)
                                    .map_err(|_| "JSON: bad \\u")?;
                            self.i += 4;
                            let mut buf = [0; 4];
                            s.extend_from_slice(
                                char::from_u32(code)
                                    .unwrap_or('?')
                                    .encode_utf8(&mut buf)
                                    .as_bytes(),
                            );
                        }
                        b'n' => s.push(b'\n'),
                        b't' => s.push(b'\t'),
                        other => s.push(other),
                    }
                }
                c => s.push(c),
            }
        }
        String::from_utf8(s).map_err(|_| "JSON: a string is not UTF-8".into())
    }

    fn object(
        &mut self,
        table: &str,
        out: &mut Vec<(String, String, Value)>,
        depth: u32,
    ) -> Result<(), String> {
        self.expect(b'{')?;
        self.ws();
        if self.b.get(self.i) == Some(&b'}') {
            self.i += 1;
            return Ok(());
        }
        loop {
            let key = self.string()?;
            self.expect(b':')?;
            self.ws();
            match self.b.get(self.i) {
                Some(b'{') if depth == 0 => self.object(&key, out, 1)?,
                Some(b'"') => {
                    let v = self.string()?;
                    out.push((table.into(), key, Value::Str(v)));
                }
                _ => {
                    let start = self.i;
                    while self.b.get(self.i).is_some_and(|c| {
                        c.is_ascii_alphanumeric() || matches!(c, b'-' | b'+' | b'.')
                    }) {
                        self.i += 1;
                    }
                    let t = std::str::from_utf8(&self.b[start..self.i]).unwrap_or("");
                    let v = parse_int(t).ok_or(format!("{key}: {t:?} is not an integer"))?;
                    out.push((table.into(), key, Value::Int(v)));
                }
            }
            self.ws();
            match self.b.get(self.i) {
                Some(b',') => self.i += 1,
                Some(b'}') => {
                    self.i += 1;
                    return Ok(());
                }
                _ => return Err(format!("JSON: ',' or '}}' expected at byte {}", self.i)),
            }
        }
    }
}

/// Now in UTC, ISO 8601 (civil date from days since 1970, H. Hinnant's
/// algorithm).
pub fn utc_now() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs()) as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        rem / 60 % 60,
        rem % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> ParamFile {
        ParamFile {
            firmware: 7060,
            date: "2026-11-27T03:00:00Z".into(),
            drive: "address 1, \"x\"".into(),
            pa: (0..PA_COUNT).map(|n| (n, n as i64 * 3)).collect(),
        }
    }

    #[test]
    fn both_formats_read_back_what_they_wrote() {
        let f = sample();
        let toml = f.to_toml();
        assert!(toml.contains("PA10 = 30"), "{toml}");
        assert!(toml.contains("# steps per revolution (steps)"), "{toml}");
        assert_eq!(ParamFile::parse(&toml).unwrap(), f);
        let json = f.to_json();
        assert!(
            json.contains("\"PA12\": \"maximum speed (r/min)\""),
            "{json}"
        );
        assert_eq!(ParamFile::parse(&json).unwrap(), f);
    }

    #[test]
    fn out_of_range_numbers_parse_so_that_the_range_check_names_the_pa() {
        let f = ParamFile::parse("firmware = 7060\n[pa]\nPA12 = 70000\nPA13 = -1\n").unwrap();
        assert_eq!(f.pa[&12], 70000);
        assert_eq!(f.pa[&13], -1);
    }

    #[test]
    fn what_is_not_a_parameter_file_is_refused_with_its_place() {
        for (text, want) in [
            ("[pa]\nPA1 = 1\n", "firmware"),
            ("firmware = 7060\n[pa]\nPA60 = 1\n", "PA60"),
            ("firmware = 7060\n[pa]\nPA1 = x\n", "line 3"),
            ("firmware = 7060\n[pa]\nPA1 = 1\nPA1 = 2\n", "twice"),
            ("firmware = 7060\ncolour = 1\n", "colour"),
            ("{\"firmware\": 7060, \"pa\": {\"PA1\": 1}", "expected"),
            ("{\"firmware\": 7060} x", "after"),
        ] {
            let e = ParamFile::parse(text).unwrap_err();
            assert!(e.contains(want), "{text}: {e}");
        }
    }

    #[test]
    fn the_date_is_iso_8601_utc() {
        let d = utc_now();
        assert_eq!(d.len(), 20, "{d}");
        assert!(d.starts_with("20") && d.ends_with('Z'), "{d}");
    }
}
