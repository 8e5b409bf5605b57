//! The emulated clock: one time line in picoseconds, advanced by executed
//! instructions at the current SYSCLK (one cycle per instruction) and by
//! skips while the core sleeps. Integer arithmetic with a carried remainder,
//! so the same run gives the same times to the picosecond.

pub const PS_PER_S: u128 = 1_000_000_000_000;

#[derive(Clone, Debug)]
pub struct Clock {
    ps: u64,
    /// Remainder of `cycles * 1e12 / sysclk` not yet in `ps`.
    rem: u128,
    sysclk: u32,
    /// Core cycles executed (not sleeping), for the CPU load figure.
    busy_cycles: u64,
    /// Cycles the core spent asleep (WFI/WFE), at the SYSCLK of the time.
    sleep_cycles: u64,
}

impl Clock {
    pub fn new(sysclk: u32) -> Self {
        Self {
            ps: 0,
            rem: 0,
            sysclk,
            busy_cycles: 0,
            sleep_cycles: 0,
        }
    }
    pub fn now(&self) -> u64 {
        self.ps
    }
    pub fn sysclk(&self) -> u32 {
        self.sysclk
    }
    /// SYSCLK changed (RCC switch): later cycles last 1/`hz`.
    pub fn set_sysclk(&mut self, hz: u32) {
        if hz != self.sysclk {
            self.rem = 0;
            self.sysclk = hz;
        }
    }
    /// The time `n` cycles from now, without advancing.
    pub fn after_cycles(&self, n: u64) -> u64 {
        self.ps + ((self.rem + n as u128 * PS_PER_S) / self.sysclk as u128) as u64
    }
    pub fn run_cycles(&mut self, n: u64) {
        let total = self.rem + n as u128 * PS_PER_S;
        self.ps += (total / self.sysclk as u128) as u64;
        self.rem = total % self.sysclk as u128;
        self.busy_cycles += n;
    }
    /// Cycles until `t` (rounded up), 0 if `t` is not in the future.
    pub fn cycles_until(&self, t: u64) -> u64 {
        if t <= self.ps {
            return 0;
        }
        let need = (t - self.ps) as u128 * self.sysclk as u128;
        (need.saturating_sub(self.rem)).div_ceil(PS_PER_S) as u64
    }
    /// Sleeps until `t` (no instructions run).
    pub fn sleep_until(&mut self, t: u64) {
        if t > self.ps {
            let c = self.cycles_until(t);
            self.sleep_cycles += c;
            self.ps = t;
            self.rem = 0;
        }
    }
    pub fn busy_cycles(&self) -> u64 {
        self.busy_cycles
    }
    pub fn sleep_cycles(&self) -> u64 {
        self.sleep_cycles
    }
}

/// Number of whole periods of a clock of `hz` in `[0, t_ps]`.
pub fn clk_at(t_ps: u64, hz: u64) -> u64 {
    (t_ps as u128 * hz as u128 / PS_PER_S) as u64
}

/// The time of edge number `c` of a clock of `hz` (rounded up to a ps).
pub fn time_of_clk(c: u64, hz: u64) -> u64 {
    (c as u128 * PS_PER_S).div_ceil(hz as u128) as u64
}
