//! `--task` on the command line: `Task`'s names from files and tables (`semi-global` also
//! accepted). The parsing lives here so the filter's `Task` stays free of the CLI crate.

use crate::particles::Task;
use clap::ValueEnum;
use clap::builder::PossibleValue;

impl ValueEnum for Task {
    fn value_variants<'a>() -> &'a [Self] {
        &Task::ALL
    }

    fn to_possible_value(&self) -> Option<PossibleValue> {
        let value = PossibleValue::new(self.name());
        Some(if *self == Task::SemiGlobal { value.alias("semi-global") } else { value })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn task_arg_spells_tasks_as_files_do() {
        for task in Task::ALL {
            assert_eq!(Task::from_str(task.name(), false), Ok(task), "the command line spells it as files");
        }
        assert_eq!(Task::from_str("semi-global", false), Ok(Task::SemiGlobal), "the hyphenated alias");
        assert!(Task::from_str("semi", false).is_err(), "no prefixes");
    }
}
