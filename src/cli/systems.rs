//! `apfn systems list`: every registered system, its stage, what it reads and writes, and its
//! parameters with their defaults (as RON, ready to paste into a schedule file).

use crate::compose::standard_registry;
use crate::params::StepData;

#[derive(clap::Subcommand, Clone, Debug, PartialEq, Eq)]
pub enum SystemsCommand {
    /// Print each system's name, stage, reads/writes, needs/produces and default parameters.
    List,
}

pub fn run(cmd: SystemsCommand) -> anyhow::Result<()> {
    match cmd {
        SystemsCommand::List => print!("{}", listing()),
    }
    Ok(())
}

/// The listing `apfn systems list` prints.
pub fn listing() -> String {
    let registry = standard_registry();
    let mut out = String::new();
    for entry in registry.entries() {
        out += &format!("{} [{:?}]\n  {}\n", entry.name, entry.stage, entry.summary);
        if !entry.needs.is_empty() {
            out += &format!("  needs: {}\n", names(&entry.needs));
        }
        if !entry.produces.is_empty() {
            out += &format!("  produces: {}\n", names(&entry.produces));
        }
        let configured = entry.with_defaults();
        out += &format!("  params: {}\n", configured.params_ron().replace('\n', "\n  "));
        for (field, defaults) in configured.optional_ron() {
            out += &format!(
                "  {field}: off by default; `{field}: Some(())` switches it on with\n    {}\n",
                defaults.replace('\n', "\n    ")
            );
        }
        out.push('\n');
    }
    out
}

/// "ParticleSet, LidarScan".
fn names(data: &[StepData]) -> String {
    data.iter().map(|d| d.name).collect::<Vec<_>>().join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn listing_names_every_system_with_its_defaults() {
        let text = listing();
        for name in standard_registry().names() {
            assert!(text.contains(&format!("{name} [")), "listing misses `{name}`");
        }
        assert!(text.contains("alpha: 0.5"), "resample's paper default α = 0.5 must be listed");
        assert!(
            text.contains("`kld: Some(())` switches it on") && text.contains("min_particles: 500"),
            "KLD's nested fields and nav2 defaults must be listed, not only `kld: None`"
        );
    }
}
