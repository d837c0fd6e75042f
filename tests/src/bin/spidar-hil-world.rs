//! `spidar world` for the hardware-in-the-loop tests. Integration tests cannot run the `spidar`
//! binary (it belongs to another package, and Cargo hands a test only its own package's
//! binaries), so the tests start this one: the same command line and the same library code as
//! `spidar world`.

use clap::Parser;

#[derive(Parser)]
#[command(name = "spidar-hil-world", about = "spidar world, for the hardware-in-the-loop tests")]
struct Cli {
    #[command(flatten)]
    world: spidar_runtime::world_process::WorldArgs,
}

fn main() -> anyhow::Result<()> {
    let mut cli = Cli::parse();
    // The tests' worlds serve no live view unless a test asks for one.
    cli.world.view.no_view |= cli.world.view.view.is_none();
    let stop = spidar_runtime::signals::Stop::install()?;
    spidar_runtime::world_process::run_world(&cli.world, &stop).map(|_| ())
}
