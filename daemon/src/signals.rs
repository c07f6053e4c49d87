//! Shutdown on SIGTERM and SIGINT: the first sets a flag the pipeline polls, so it drains and
//! writes its outputs; a second SIGINT (an impatient Ctrl-C) exits at once.

use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use anyhow::{Context, Result};
use signal_hook::consts::{SIGINT, SIGTERM};

/// Sets `stop` on SIGTERM or SIGINT.
pub fn stop_on_signals(stop: &Arc<AtomicBool>) -> Result<()> {
    // Order matters: the conditional exit is checked before the flag is set by this signal.
    signal_hook::flag::register_conditional_shutdown(SIGINT, 130, stop.clone())
        .context("cannot install the SIGINT handler")?;
    for signal in [SIGINT, SIGTERM] {
        signal_hook::flag::register(signal, stop.clone())
            .context("cannot install the signal handlers")?;
    }
    Ok(())
}
