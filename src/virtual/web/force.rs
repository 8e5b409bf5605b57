//! Switches of the simulated axis forced from the page: a commissioning
//! engineer presses a limit or home switch by hand to see what the drive
//! does. A forced switch replaces the state the axis position gives
//! (`--cw-limit`, `--ccw-limit`, `--home-switch`) until it is released.

use modbus_drive::device::sim::SwitchView;
use modbus_drive::motion::Switches;

/// One of the three switch inputs (SPEC §8.6, §8.7).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Switch {
    CwLimit,
    CcwLimit,
    Home,
}

impl Switch {
    pub fn parse(name: &str) -> Option<Self> {
        match name {
            "cw" => Some(Self::CwLimit),
            "ccw" => Some(Self::CcwLimit),
            "home" => Some(Self::Home),
            _ => None,
        }
    }
}

/// Per switch: `None` follows the axis, `Some(state)` forces it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Forced {
    cw: Option<bool>,
    ccw: Option<bool>,
    home: Option<bool>,
}

impl Forced {
    pub fn set(&mut self, switch: Switch, state: Option<bool>) {
        *self.slot(switch) = state;
    }

    pub fn get(&self, switch: Switch) -> Option<bool> {
        match switch {
            Switch::CwLimit => self.cw,
            Switch::CcwLimit => self.ccw,
            Switch::Home => self.home,
        }
    }

    fn slot(&mut self, switch: Switch) -> &mut Option<bool> {
        match switch {
            Switch::CwLimit => &mut self.cw,
            Switch::CcwLimit => &mut self.ccw,
            Switch::Home => &mut self.home,
        }
    }

    /// The states the drive sees: the axis's, with forced ones replaced.
    pub fn apply(&self, axis: Switches) -> Switches {
        Switches::new(
            self.cw.unwrap_or(axis.cw_limit()),
            self.ccw.unwrap_or(axis.ccw_limit()),
            self.home.unwrap_or(axis.home()),
        )
    }
}

/// The simulation host hands the drive the forced states.
impl SwitchView for Forced {
    fn seen(&self, axis: Switches) -> Switches {
        self.apply(axis)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn forced_switches_replace_the_axis_until_released() {
        let axis = Switches::new(true, false, false);
        let mut f = Forced::default();
        assert_eq!(f.apply(axis), axis);
        f.set(Switch::CwLimit, Some(false));
        f.set(Switch::Home, Some(true));
        let seen = f.apply(axis);
        assert!(!seen.cw_limit() && !seen.ccw_limit() && seen.home());
        f.set(Switch::CwLimit, None);
        assert!(f.apply(axis).cw_limit());
        assert_eq!(f.get(Switch::Home), Some(true));
        assert_eq!(Switch::parse("ccw"), Some(Switch::CcwLimit));
        assert_eq!(Switch::parse("x"), None);
    }
}
