//! Robot profiles: what the robot can reach, lift, grasp and push, and where
//! its camera sits and how wide it sees. Read from TOML; two are shipped
//! (`default`, `weak-arm`). The camera's resolution is not the robot's: it
//! is the run's (`[task] image_size`, what the networks take), given to the
//! [`Simulator`](crate::agent::Simulator) when it is made.

use serde::Deserialize;

/// A robot's abilities and camera.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotProfile {
    /// Name, for logs.
    pub name: String,
    /// Farthest an object may be from the camera to be picked up or pushed, metres.
    pub reach_m: f32,
    /// Heaviest object it can pick up, kg (`inf`: no limit).
    pub payload_kg: f32,
    /// Widest object (smallest horizontal box side) it can grasp, metres (`inf`: no limit).
    pub gripper_opening_m: f32,
    /// Force of a push, newtons.
    pub push_force_n: f32,
    /// Camera height above the floor, metres.
    pub camera_height_m: f32,
    /// Horizontal field of view, degrees.
    pub fov_deg: f32,
    /// Radius of the agent's capsule, metres.
    pub agent_radius_m: f32,
    /// Height of the agent's capsule, metres.
    pub agent_height_m: f32,
}

/// Why a profile could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ProfileError {
    /// The file could not be read.
    #[error("cannot read robot profile {path}: {source}")]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// Not a valid profile.
    #[error("robot profile {origin}: {message}")]
    Invalid {
        /// File or shipped name.
        origin: String,
        /// What is wrong.
        message: String,
    },
    /// No shipped profile of that name.
    #[error(
        "no shipped robot profile {0:?}: use `default`, `weak-arm`, or a path to a .toml file"
    )]
    Unknown(String),
}

const SHIPPED: [(&str, &str); 2] = [
    ("default", include_str!("../profiles/default.toml")),
    ("weak-arm", include_str!("../profiles/weak-arm.toml")),
];

impl RobotProfile {
    /// Parses a profile and checks its values.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self, ProfileError> {
        let invalid = |message: String| ProfileError::Invalid {
            origin: origin.to_string(),
            message,
        };
        if toml::from_str::<toml::Table>(text).is_ok_and(|t| t.contains_key("image_size")) {
            return Err(invalid(
                "image_size is no longer a robot setting: remove it; the camera's resolution is the run's `[task] image_size`".into(),
            ));
        }
        let p: Self = toml::from_str(text).map_err(|e| invalid(e.to_string()))?;
        for (field, value) in [
            ("reach_m", p.reach_m),
            ("payload_kg", p.payload_kg),
            ("gripper_opening_m", p.gripper_opening_m),
            ("push_force_n", p.push_force_n),
            ("camera_height_m", p.camera_height_m),
            ("agent_radius_m", p.agent_radius_m),
            ("agent_height_m", p.agent_height_m),
        ] {
            if value.is_nan() || value <= 0.0 {
                return Err(invalid(format!("{field} must be positive, got {value}")));
            }
        }
        if !(1.0..179.0).contains(&p.fov_deg) {
            return Err(invalid(format!(
                "fov_deg must be in 1..179, got {}",
                p.fov_deg
            )));
        }
        if p.camera_height_m > p.agent_height_m {
            return Err(invalid("camera_height_m exceeds agent_height_m".into()));
        }
        Ok(p)
    }

    /// A shipped profile (`default`, `weak-arm`) or a TOML file.
    pub fn load(name_or_path: &str) -> Result<Self, ProfileError> {
        if let Some((_, text)) = SHIPPED.iter().find(|(n, _)| *n == name_or_path) {
            return Self::from_toml(text, name_or_path);
        }
        let path = std::path::Path::new(name_or_path);
        if path.extension().is_some_and(|e| e == "toml") || path.exists() {
            let text = std::fs::read_to_string(path).map_err(|source| ProfileError::Io {
                path: path.to_owned(),
                source,
            })?;
            return Self::from_toml(&text, name_or_path);
        }
        Err(ProfileError::Unknown(name_or_path.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_profiles_load_and_bad_ones_are_explained() {
        let d = RobotProfile::load("default").unwrap();
        assert!(d.payload_kg.is_infinite() && d.reach_m == 1.5);
        let w = RobotProfile::load("weak-arm").unwrap();
        assert!(w.payload_kg < 2.3, "a laptop (2.3 kg) must be too heavy");
        let e = RobotProfile::load("strong-arm").unwrap_err();
        assert!(e.to_string().contains("weak-arm"), "{e}");
        let text =
            include_str!("../profiles/default.toml").replace("reach_m = 1.5", "reach_m = -1");
        let e = RobotProfile::from_toml(&text, "x.toml").unwrap_err();
        assert!(e.to_string().contains("reach_m must be positive"), "{e}");
        let e = RobotProfile::from_toml("name = \"a\"\nspeed = 3", "y.toml").unwrap_err();
        assert!(e.to_string().contains("y.toml"), "{e}");
        // A profile written before the resolution moved to the run's task.
        let old = format!(
            "{}\nimage_size = 128\n",
            include_str!("../profiles/default.toml")
        );
        let e = RobotProfile::from_toml(&old, "old.toml").unwrap_err();
        assert!(e.to_string().contains("[task] image_size"), "{e}");
    }
}
