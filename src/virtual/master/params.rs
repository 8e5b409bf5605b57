//! `params save` and `params restore`: the drive's PA0..PA59 to a file and
//! back onto this or another drive of the same firmware.
//!
//! Restore checks the whole file before it sends a single write (firmware
//! version, each value against its PA's range and access), shows the
//! differences, and only with `--yes` writes the changed PAs, reads each
//! back, and ends with EE-Set so that the set survives a power cycle. The
//! line PAs (address, baud, format) are written last: the drive answers at
//! its new address and line from the reply after, so the master follows
//! it for the read-back and the EE-Set.

use std::collections::BTreeMap;
use std::time::Duration;

use super::cli::{Common, Params};
use super::params_file::{utc_now, ParamFile};
use super::{LineSpec, Master};
use crate::virtual_drive::registers::{
    pa_def, pa_meta, PA_ADDRESS, PA_BASE, PA_BAUD, PA_FIRMWARE, PA_FORMAT,
};

/// The EE command register and EE-Set (SPEC §9).
const EE_REGISTER: u16 = 0x003A;
const EE_SET: u16 = 1;
/// An EE-Set answers once the flash is written.
const EE_TIMEOUT: Duration = Duration::from_secs(3);

fn master(c: &Common) -> Master {
    let timeout = c.timeout.unwrap_or(c.endpoint.default_timeout());
    Master::new(c.endpoint.clone(), c.address, timeout)
}

pub fn save(o: Params) -> Result<(), String> {
    let mut m = master(&o.common);
    let pas = m
        .read_pas()
        .map_err(|e| format!("reading PA0..PA59: {e}"))?;
    let file = ParamFile {
        firmware: i64::from(pas[PA_FIRMWARE]),
        date: utc_now(),
        drive: format!("address {}, {}", m.unit, m.describe()),
        pa: pas
            .iter()
            .enumerate()
            .map(|(n, v)| (n, i64::from(*v)))
            .collect(),
    };
    let json = o.file.extension().is_some_and(|e| e == "json");
    let text = if json { file.to_json() } else { file.to_toml() };
    std::fs::write(&o.file, text).map_err(|e| format!("{}: {e}", o.file.display()))?;
    eprintln!(
        "saved PA0..PA59 of firmware {} to {}",
        file.firmware,
        o.file.display()
    );
    Ok(())
}

/// Why the file's PA `n` = `v` cannot be written to a drive that holds
/// `current`, if it cannot.
fn refusal(n: usize, v: i64, current: u16) -> Option<String> {
    let def = pa_def(n)?;
    let (name, _) = pa_meta(n);
    if def.read_only() {
        return (v != i64::from(current))
            .then(|| format!("PA{n} ({name}) is read-only: {v} cannot replace {current}"));
    }
    if !u16::try_from(v).is_ok_and(|v| def.contains(v)) {
        return Some(format!(
            "PA{n} ({name}) = {v} is out of its range {}",
            def.range()
        ));
    }
    None
}

/// The changes the file makes to `current`, or why it is refused as a
/// whole (nothing is written then).
pub fn plan(file: &ParamFile, current: &[u16]) -> Result<Vec<(usize, u16, u16)>, String> {
    let firmware = current[PA_FIRMWARE];
    if file.firmware != i64::from(firmware) {
        return Err(format!(
            "the file is from firmware {} and the drive runs firmware {firmware} (PA{PA_FIRMWARE}): \
             parameters may mean other things there; nothing written",
            file.firmware
        ));
    }
    let mut why = Vec::new();
    for (&n, &v) in &file.pa {
        if let Some(r) = refusal(n, v, current[n]) {
            why.push(r);
        }
    }
    if !why.is_empty() {
        return Err(format!("{}; nothing written", why.join("; ")));
    }
    let mut changes: Vec<(usize, u16, u16)> = file
        .pa
        .iter()
        .filter(|(&n, &v)| i64::from(current[n]) != v)
        .map(|(&n, &v)| (n, current[n], v as u16))
        .collect();
    // the line PAs last, address last of all
    let rank = |n: usize| match n {
        PA_BAUD | PA_FORMAT => 1,
        PA_ADDRESS => 2,
        _ => 0,
    };
    changes.sort_by_key(|&(n, _, _)| (rank(n), n));
    Ok(changes)
}

pub fn restore(o: Params) -> Result<(), String> {
    let text =
        std::fs::read_to_string(&o.file).map_err(|e| format!("{}: {e}", o.file.display()))?;
    let file = ParamFile::parse(&text).map_err(|e| format!("{}: {e}", o.file.display()))?;
    let mut m = master(&o.common);
    let current = m
        .read_pas()
        .map_err(|e| format!("reading PA0..PA59: {e}"))?;
    let changes = plan(&file, &current)?;
    if changes.is_empty() {
        println!(
            "the drive already holds every value of {}",
            o.file.display()
        );
    }
    for &(n, old, new) in &changes {
        println!("PA{n:<2} {:<44} {old} -> {new}", pa_meta(n).0);
    }
    if !o.yes {
        if !changes.is_empty() {
            println!(
                "{} change(s); run again with --yes to write them",
                changes.len()
            );
        }
        return Ok(());
    }
    let mut line_pas: BTreeMap<usize, u16> = [PA_BAUD, PA_FORMAT]
        .into_iter()
        .map(|n| (n, current[n]))
        .collect();
    for (i, &(n, _, new)) in changes.iter().enumerate() {
        let done = |i: usize| {
            if i == 0 {
                "nothing was written".to_string()
            } else {
                format!("PA{} were written (not saved)", list(&changes[..i]))
            }
        };
        m.write(PA_BASE + n as u16, new)
            .map_err(|e| format!("PA{n} = {new}: {e}; {}", done(i)))?;
        // The drive now answers at its new address / line (SPEC §7).
        if n == PA_ADDRESS {
            m.unit = new as u8;
        }
        if let Some(v) = line_pas.get_mut(&n) {
            *v = new;
            let line = LineSpec::from_pa(line_pas[&PA_BAUD], line_pas[&PA_FORMAT])
                .ok_or(format!("PA{n} = {new}: not a line setting"))?;
            m.set_line(line).map_err(|e| format!("{e}"))?;
        }
        let back = m
            .read(PA_BASE + n as u16, 1)
            .map_err(|e| format!("reading PA{n} back: {e}; {}", done(i + 1)))?;
        if back[0] != new {
            return Err(format!(
                "PA{n} reads back {} after writing {new}; {}",
                back[0],
                done(i + 1)
            ));
        }
    }
    m.timeout = EE_TIMEOUT;
    m.write_words(EE_REGISTER, &[EE_SET])
        .map_err(|e| format!("EE-Set: {e}; the values are in the working set, not saved"))?;
    println!(
        "wrote {} change(s), read each back, saved them (EE-Set)",
        changes.len()
    );
    Ok(())
}

fn list(changes: &[(usize, u16, u16)]) -> String {
    changes
        .iter()
        .map(|(n, _, _)| n.to_string())
        .collect::<Vec<_>>()
        .join(", PA")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::virtual_drive::registers::{PA, PA_COUNT};

    fn defaults() -> Vec<u16> {
        PA.iter().map(|d| d.default()).collect()
    }

    fn file(pairs: &[(usize, i64)]) -> ParamFile {
        let d = defaults();
        let mut pa: BTreeMap<usize, i64> = (0..PA_COUNT).map(|n| (n, i64::from(d[n]))).collect();
        pa.extend(pairs.iter().copied());
        ParamFile {
            firmware: i64::from(d[PA_FIRMWARE]),
            date: String::new(),
            drive: String::new(),
            pa,
        }
    }

    #[test]
    fn only_changed_values_are_written_the_line_pas_last() {
        let c = plan(
            &file(&[(51, 17), (12, 1500), (52, 1), (53, 1)]),
            &defaults(),
        )
        .unwrap();
        let order: Vec<usize> = c.iter().map(|x| x.0).collect();
        assert_eq!(order, [12, 52, 53, 51]);
        assert_eq!(c[0], (12, 3000, 1500));
        assert!(plan(&file(&[]), &defaults()).unwrap().is_empty());
    }

    #[test]
    fn an_out_of_range_value_or_another_firmware_refuses_the_whole_file() {
        let e = plan(&file(&[(12, 1500), (51, 300)]), &defaults()).unwrap_err();
        assert!(e.contains("PA51") && e.contains("1..=247"), "{e}");
        assert!(e.contains("nothing written"), "{e}");
        let e = plan(&file(&[(13, -1)]), &defaults()).unwrap_err();
        assert!(e.contains("PA13"), "{e}");
        let mut f = file(&[]);
        f.firmware += 1;
        let e = plan(&f, &defaults()).unwrap_err();
        assert!(e.contains("firmware"), "{e}");
    }
}
