//! Facts about the boards the firmware runs on that the core's users must
//! agree on, without any HAL: the firmware takes its step tick from here,
//! the virtual drive (`--board`) and the tests run the core at the same
//! tick, so that every board's limits can be seen and tested on a host.

/// A board the firmware is built for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Board {
    /// STM32G431CB (Cortex-M4F, 170 MHz).
    G431,
    /// STM32F103C8 (Cortex-M3, 72 MHz, "blue pill").
    F103,
}

impl Board {
    /// Every board, the primary one first.
    pub const ALL: [Board; 2] = [Board::G431, Board::F103];

    /// Step timer tick, Hz: the unit the planner times steps in
    /// (`motion::PlannerConfig::tick_hz`). The step timer's own clock (no
    /// prescaler): the finest grid its pulses can keep, and what the
    /// shortest entries of its DMA bursts are counted in.
    pub const fn step_tick_hz(self) -> u32 {
        match self {
            Board::G431 => 170_000_000,
            Board::F103 => 72_000_000,
        }
    }

    /// Highest step rate, steps/s: at most the rate at which this board's
    /// step engine (src/firmware/steps.rs) makes every pulse on time with
    /// a master polling throughout — the figure `fw-sim/measure.py` finds
    /// under emulation ("Highest step rate with every pulse on time" in
    /// docs/generated/fw-sim.md, on its 50 000 steps/s grid) — and never
    /// above the planner's ceiling for the image's ring
    /// (`motion::MAX_STEP_RATE`; each image checks its board at compile
    /// time). The drive clamps every speed to it as it clamps to PA12
    /// (SPEC §8.4, docs/drive.md "Units and limits"): no board accepts a
    /// speed it cannot step on time. PA15's pulse width clamps further
    /// (`Params::step_rate_cap`).
    pub const fn max_step_rate(self) -> u32 {
        // one arm a board: fw-sim/measure.py and the tests read them
        match self {
            Board::G431 => 1_000_000,
            Board::F103 => 500_000,
        }
    }

    /// Highest acceleration and deceleration, steps/s²: the planner's
    /// ceiling (`motion::MAX_ACCEL`, which the planner checks it against)
    /// on both boards, whose step engines keep every ramp at it on time up
    /// to [`Board::max_step_rate`].
    pub const fn max_accel(self) -> u64 {
        match self {
            Board::G431 | Board::F103 => 2_000_000,
        }
    }

    /// The chip, as the firmware reports it in 0x1009.
    pub const fn chip(self) -> &'static str {
        match self {
            Board::G431 => "STM32G431CB",
            Board::F103 => "STM32F103C8",
        }
    }

    /// The short name the virtual drive's `--board` takes.
    pub const fn short_name(self) -> &'static str {
        match self {
            Board::G431 => "g431",
            Board::F103 => "f103",
        }
    }

    /// The board whose [`Board::short_name`] is `name` (case-insensitive).
    pub fn from_short_name(name: &str) -> Option<Board> {
        Self::ALL
            .into_iter()
            .find(|b| b.short_name().eq_ignore_ascii_case(name))
    }
}
