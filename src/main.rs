use clap::Parser;

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt().with_env_filter(tracing_subscriber::EnvFilter::from_default_env()).init();
    apfn::cli::run(apfn::cli::Cli::parse())
}
