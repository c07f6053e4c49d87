//! `glintd`'s library: the pipeline and each subcommand, one module apiece, so that the
//! end-to-end tests drive the same code the binary ships. The binary (`main.rs`) only parses
//! the command line, sets up logging and prints errors. `demo` and `sim` exist only with the
//! `sim` feature (on by default), so a build without it does not link the simulator.

/// Prints a line to stdout; a closed pipe (`glintd info … | head`) ends the program quietly
/// instead of panicking as `println!` would.
macro_rules! say {
    ($($arg:tt)*) => {
        $crate::print_line(format_args!($($arg)*))
    };
}

pub mod bench_cmd;
pub mod bridge_cmd;
pub mod capture;
pub mod config;
pub mod decode_cmd;
#[cfg(feature = "sim")]
pub mod demo_cmd;
pub mod echo_cmd;
pub mod eval_cmd;
pub mod info_cmd;
pub mod initial_pose_cmd;
pub mod map_cmd;
pub mod outputs;
pub mod pipeline;
pub mod posegraph_cmd;
pub mod publish;
pub mod record_cmd;
pub mod replay_cmd;
pub mod run_cmd;
pub mod signals;
#[cfg(feature = "sim")]
pub mod sim_cmd;
#[cfg(feature = "sim")]
pub mod simulated;
#[cfg(feature = "sim")]
pub mod soak_cmd;

/// Writes one line to stdout (see `say!`).
pub fn print_line(args: std::fmt::Arguments<'_>) {
    use std::io::Write;
    if let Err(e) = writeln!(std::io::stdout().lock(), "{args}") {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            std::process::exit(0);
        }
        eprintln!("glintd: cannot write to stdout: {e}");
        std::process::exit(1);
    }
}
