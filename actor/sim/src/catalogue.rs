//! The object catalogue that procedural rooms are drawn from: per object
//! type its flags (as probabilities where iTHOR mixes them), size and size
//! range, mass, where it stands and how often it appears. Built from the
//! facts in `ithor-object-types.tsv` and kept in the project's own TOML
//! format, so users can edit a catalogue or write their own.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// Where objects of a type are placed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Placement {
    /// Standing on the floor.
    Floor,
    /// On top of a receptacle.
    Surface,
    /// Hung on a wall.
    Wall,
    /// On the floor with probability `floor_share`, otherwise on a surface.
    FloorOrSurface {
        /// Fraction placed on the floor.
        floor_share: f32,
    },
}

/// One object type.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CatalogueEntry {
    /// AI2-THOR object type, e.g. `Sofa`.
    #[serde(rename = "type")]
    pub object_type: String,
    /// Probability that an instance can be picked up.
    pub pickupable: f32,
    /// Probability that an instance can be moved (pushed) without picking it up.
    pub moveable: f32,
    /// Probability that an instance is a receptacle.
    pub receptacle: f32,
    /// Whether instances open (drawers, books).
    pub openable: bool,
    /// Typical size: width, depth, height, metres.
    pub size_m: [f32; 3],
    /// Smallest width, depth, height seen, metres.
    pub size_min_m: [f32; 3],
    /// Largest width, depth, height seen, metres.
    pub size_max_m: [f32; 3],
    /// Typical mass, kg (0 for static objects).
    pub mass_kg: f32,
    /// Where it stands.
    pub placement: Placement,
    /// Fraction of rooms that have at least one.
    pub presence: f32,
    /// Mean number of instances in a room that has one.
    pub mean_count: f32,
}

/// A set of object types.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Catalogue {
    /// The types.
    #[serde(rename = "object")]
    pub entries: Vec<CatalogueEntry>,
}

/// Why a catalogue could not be read.
#[derive(Debug, thiserror::Error)]
pub enum CatalogueError {
    /// The file could not be read.
    #[error("cannot read the object catalogue {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The reason.
        source: std::io::Error,
    },
    /// A line of the TSV does not parse.
    #[error("{path}, line {line}: {reason}")]
    Tsv {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        reason: String,
    },
    /// The TOML does not parse.
    #[error("{path} is not a valid catalogue: {source}")]
    Toml {
        /// The file.
        path: PathBuf,
        /// The reason.
        source: toml::de::Error,
    },
    /// No type could be placed.
    #[error("{path} has no object type that procedural rooms can place")]
    Empty {
        /// The file.
        path: PathBuf,
    },
}

/// Number of rooms the TSV's counts come from (FloorPlan201–230).
const ITHOR_ROOMS: f32 = 30.0;

impl Catalogue {
    /// Reads a catalogue: `.tsv` files in the format of
    /// `ithor-object-types.tsv`, anything else as the project's TOML.
    pub fn load(path: &Path) -> Result<Self, CatalogueError> {
        let text = std::fs::read_to_string(path).map_err(|source| CatalogueError::Io {
            path: path.to_owned(),
            source,
        })?;
        let catalogue = if path.extension().is_some_and(|e| e == "tsv") {
            Self::from_tsv(&text, path)?
        } else {
            toml::from_str(&text).map_err(|source| CatalogueError::Toml {
                path: path.to_owned(),
                source,
            })?
        };
        if catalogue.entries.is_empty() {
            return Err(CatalogueError::Empty {
                path: path.to_owned(),
            });
        }
        Ok(catalogue)
    }

    /// The catalogue as the project's TOML.
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a catalogue always serialises")
    }

    /// Parses the iTHOR object-type table. Types without a placement that
    /// rooms are built from (structural floor, parts of furniture) are left out.
    pub fn from_tsv(text: &str, path: &Path) -> Result<Self, CatalogueError> {
        let mut lines = text.lines().enumerate();
        let (_, header) = lines.next().ok_or_else(|| CatalogueError::Tsv {
            path: path.to_owned(),
            line: 1,
            reason: "empty file".into(),
        })?;
        let columns: Vec<&str> = header.split('\t').collect();
        let column = |name: &str| {
            columns
                .iter()
                .position(|c| c.starts_with(name))
                .ok_or_else(|| CatalogueError::Tsv {
                    path: path.to_owned(),
                    line: 1,
                    reason: format!("no column `{name}`"),
                })
        };
        let at = Columns {
            object_type: column("type")?,
            pickupable: column("pickupable")?,
            moveable: column("moveable")?,
            receptacle: column("receptacle")?,
            openable: column("openable")?,
            size: column("typical_size_m")?,
            range: column("size_range_m")?,
            mass: column("typical_mass_kg")?,
            location: column("typical_location")?,
            instances: column("instances_in_")?,
            scenes: column("scenes_present")?,
        };
        let mut entries = Vec::new();
        for (index, line) in lines {
            if line.trim().is_empty() {
                continue;
            }
            let fields: Vec<&str> = line.split('\t').collect();
            let entry = parse_row(&fields, &at).map_err(|reason| CatalogueError::Tsv {
                path: path.to_owned(),
                line: index + 1,
                reason,
            })?;
            entries.extend(entry);
        }
        Ok(Self { entries })
    }
}

/// Column indices of the TSV.
struct Columns {
    object_type: usize,
    pickupable: usize,
    moveable: usize,
    receptacle: usize,
    openable: usize,
    size: usize,
    range: usize,
    mass: usize,
    location: usize,
    instances: usize,
    scenes: usize,
}

fn parse_row(fields: &[&str], at: &Columns) -> Result<Option<CatalogueEntry>, String> {
    let get = |i: usize| {
        fields
            .get(i)
            .map(|s| s.trim())
            .ok_or_else(|| format!("only {} columns", fields.len()))
    };
    let Some(placement) = placement(get(at.location)?) else {
        return Ok(None);
    };
    let size = triple(get(at.size)?, " x ")?;
    let (mut lo, mut hi) = (size, size);
    for (axis, span) in get(at.range)?.split(';').enumerate().take(3) {
        let (a, b) = span
            .split_once('-')
            .ok_or_else(|| format!("size range `{span}` is not `min-max`"))?;
        lo[axis] = number(a)?;
        hi[axis] = number(b)?;
    }
    let instances = number(get(at.instances)?)?;
    let scenes = number(get(at.scenes)?)?.max(1.0);
    Ok(Some(CatalogueEntry {
        object_type: get(at.object_type)?.to_string(),
        pickupable: flag(get(at.pickupable)?)?,
        moveable: flag(get(at.moveable)?)?,
        receptacle: flag(get(at.receptacle)?)?,
        openable: flag(get(at.openable)?)? > 0.5,
        size_m: size,
        size_min_m: lo,
        size_max_m: hi,
        mass_kg: get(at.mass)?
            .split_whitespace()
            .next()
            .and_then(|m| m.parse().ok())
            .unwrap_or(0.0),
        placement,
        presence: (scenes / ITHOR_ROOMS).min(1.0),
        mean_count: instances / scenes,
    }))
}

/// `yes` → 1, `no` → 0, `mixed(a/b)` → a / b.
fn flag(text: &str) -> Result<f32, String> {
    match text {
        "yes" => Ok(1.0),
        "no" => Ok(0.0),
        mixed => {
            let inner = mixed
                .strip_prefix("mixed(")
                .and_then(|s| s.strip_suffix(')'))
                .ok_or_else(|| format!("flag `{mixed}` is not yes, no or mixed(a/b)"))?;
            let (a, b) = inner
                .split_once('/')
                .ok_or_else(|| format!("flag `{mixed}` is not mixed(a/b)"))?;
            Ok(number(a)? / number(b)?.max(1.0))
        }
    }
}

fn number(text: &str) -> Result<f32, String> {
    text.trim()
        .parse()
        .map_err(|_| format!("`{text}` is not a number"))
}

fn triple(text: &str, separator: &str) -> Result<[f32; 3], String> {
    let parts: Vec<&str> = text.split(separator).collect();
    if parts.len() != 3 {
        return Err(format!("`{text}` is not three sizes"));
    }
    Ok([number(parts[0])?, number(parts[1])?, number(parts[2])?])
}

/// The placement in a `typical_location` cell; `None` for types rooms are
/// not built from (the structural floor, parts of furniture).
fn placement(location: &str) -> Option<Placement> {
    if location.starts_with("structural") || location.starts_with("part-of-furniture") {
        return None;
    }
    if let Some(rest) = location.strip_prefix("floor or on-surface") {
        // "floor or on-surface (11 floor/18 surface)"
        let counts: Vec<f32> = rest
            .split(|c: char| !c.is_ascii_digit())
            .filter_map(|s| s.parse().ok())
            .collect();
        let floor_share = match counts[..] {
            [floor, surface] if floor + surface > 0.0 => floor / (floor + surface),
            _ => 0.5,
        };
        return Some(Placement::FloorOrSurface { floor_share });
    }
    Some(if location.starts_with("floor") {
        Placement::Floor
    } else if location.starts_with("wall") {
        Placement::Wall
    } else {
        Placement::Surface
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flags_and_placements_parse() {
        assert_eq!(flag("mixed(13/16)").unwrap(), 13.0 / 16.0);
        assert!(flag("maybe").is_err());
        assert_eq!(placement("floor (10/13)"), Some(Placement::Floor));
        assert_eq!(
            placement("floor or on-surface (11 floor/18 surface)"),
            Some(Placement::FloorOrSurface {
                floor_share: 11.0 / 29.0
            })
        );
        assert_eq!(placement("part-of-furniture (static)"), None);
        assert_eq!(
            placement("on-surface (TVStand/Dresser) or wall-mounted (static)"),
            Some(Placement::Surface)
        );
    }
}
