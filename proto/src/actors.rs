//! How a run's actors run, as its `config.toml` says (`[actors]`): every
//! actor the run starts, and `actor evaluate` on the run, read these, so no
//! flag has to be repeated and a resumed run's actors run as before. Unlike
//! the task, these may change between starts of a run (another machine,
//! another renderer); an actor's own flags override them.

use serde::{Deserialize, Serialize};

/// Renderers an actor can use.
pub const RENDERERS: [&str; 3] = ["auto", "gpu", "cpu"];
/// Room sets actors train in.
pub const TRAINING_SCENES: [&str; 2] = ["ithor", "generated"];
/// Devices an actor infers on.
pub const ACTOR_DEVICES: [&str; 2] = ["cpu", "gpu"];

/// The `[actors]` table of a run's config.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, documented::DocumentedFields)]
#[serde(default, deny_unknown_fields)]
pub struct ActorSettings {
    /// Robot profile: a shipped name (default, weak-arm) or a TOML file.
    pub profile: String,
    /// Renderer: auto (gpu when a Vulkan adapter exists, else cpu), gpu
    /// (wgpu: a GPU or Mesa lavapipe) or cpu (ray casting).
    pub renderer: String,
    /// Rooms the actors train in: ithor (FloorPlan201–220 under the data
    /// directory) or generated (procedural rooms from its catalogue).
    pub scenes: String,
    /// Where actors run their networks: cpu, or gpu in a build with
    /// `--features nets/gpu`.
    pub device: String,
    /// Environments each actor process steps, a thread each (1..=256).
    pub envs: u16,
    /// The data directory (ithor-livingrooms/, ithor-object-types.tsv);
    /// unset: each actor's own default (`AFX_DATA`, else ../shared/data).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub data: Option<String>,
}

impl Default for ActorSettings {
    fn default() -> Self {
        Self {
            profile: "default".into(),
            renderer: "auto".into(),
            scenes: "ithor".into(),
            device: "cpu".into(),
            envs: 1,
            data: None,
        }
    }
}

/// A value `[actors]` does not accept.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("actors.{field} = {value:?} is not one of {allowed}")]
pub struct ActorSettingsError {
    /// The setting.
    pub field: &'static str,
    /// What it said.
    pub value: String,
    /// What it may say.
    pub allowed: String,
}

impl ActorSettings {
    /// Checks every value against what actors accept.
    pub fn validate(&self) -> Result<(), ActorSettingsError> {
        let one_of = |field: &'static str, value: &str, allowed: &[&str]| {
            if allowed.contains(&value) {
                Ok(())
            } else {
                Err(ActorSettingsError {
                    field,
                    value: value.to_string(),
                    allowed: allowed.join(", "),
                })
            }
        };
        one_of("renderer", &self.renderer, &RENDERERS)?;
        one_of("scenes", &self.scenes, &TRAINING_SCENES)?;
        one_of("device", &self.device, &ACTOR_DEVICES)?;
        if !(1..=256).contains(&self.envs) {
            return Err(ActorSettingsError {
                field: "envs",
                value: self.envs.to_string(),
                allowed: "1..=256".into(),
            });
        }
        if self.profile.is_empty() {
            return Err(ActorSettingsError {
                field: "profile",
                value: String::new(),
                allowed: "a profile name or a TOML file".into(),
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_other_values_are_named_in_the_error() {
        ActorSettings::default().validate().unwrap();
        let bad = ActorSettings {
            renderer: "vulkan".into(),
            ..ActorSettings::default()
        };
        let err = bad.validate().unwrap_err().to_string();
        assert!(
            err.contains("actors.renderer") && err.contains("auto, gpu, cpu"),
            "{err}"
        );
        let none = ActorSettings {
            envs: 0,
            ..ActorSettings::default()
        };
        assert_eq!(none.validate().unwrap_err().field, "envs");
    }
}
