//! Crash-safe checkpoints: `checkpoints/<step>/` holding the files plus a
//! `manifest.json` with every file's size and SHA-256.
//!
//! A checkpoint is written into a temporary directory, each file fsynced, then
//! renamed into place and the parent fsynced, so a crash leaves either the
//! whole checkpoint or none. Loading verifies the manifest and falls back to an
//! older checkpoint when the newest is damaged.

use std::collections::BTreeMap;
use std::fs::{self, File};
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

const MANIFEST: &str = "manifest.json";

#[derive(Debug, Serialize, Deserialize)]
struct Manifest {
    step: u64,
    files: Vec<ManifestEntry>,
}

#[derive(Debug, Serialize, Deserialize)]
struct ManifestEntry {
    name: String,
    size: u64,
    sha256: String,
}

/// A checkpoint read back and verified.
#[derive(Debug)]
pub struct LoadedCheckpoint {
    /// The step it was written at.
    pub step: u64,
    /// Its directory.
    pub dir: PathBuf,
    /// File name → contents, every one verified against the manifest.
    pub files: BTreeMap<String, Vec<u8>>,
    /// Newer checkpoints that failed verification, with the reason.
    pub skipped: Vec<(PathBuf, String)>,
}

fn sha256_hex(bytes: &[u8]) -> String {
    hex::encode(Sha256::digest(bytes))
}

fn write_synced(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    let mut file = File::create(path).with_context(|| format!("creating {}", path.display()))?;
    file.write_all(bytes)
        .with_context(|| format!("writing {}", path.display()))?;
    file.sync_all()
        .with_context(|| format!("syncing {}", path.display()))
}

fn sync_dir(path: &Path) -> anyhow::Result<()> {
    File::open(path)
        .and_then(|d| d.sync_all())
        .with_context(|| format!("syncing directory {}", path.display()))
}

/// Writes `files` as checkpoint `step` under `root` and deletes all but the
/// newest `keep` checkpoints. Returns the checkpoint's directory.
pub fn write(
    root: &Path,
    step: u64,
    files: &[(&str, &[u8])],
    keep: usize,
) -> anyhow::Result<PathBuf> {
    fs::create_dir_all(root)
        .with_context(|| format!("creating checkpoint directory {}", root.display()))?;
    let target = root.join(step.to_string());
    if target.exists() {
        return Ok(target);
    }
    let tmp = root.join(format!(".tmp-{step}-{}", std::process::id()));
    if tmp.exists() {
        fs::remove_dir_all(&tmp).with_context(|| format!("removing stale {}", tmp.display()))?;
    }
    fs::create_dir(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
    let mut entries = Vec::new();
    for (name, bytes) in files {
        write_synced(&tmp.join(name), bytes)?;
        entries.push(ManifestEntry {
            name: (*name).to_string(),
            size: bytes.len() as u64,
            sha256: sha256_hex(bytes),
        });
    }
    let manifest = serde_json::to_vec_pretty(&Manifest {
        step,
        files: entries,
    })?;
    write_synced(&tmp.join(MANIFEST), &manifest)?;
    sync_dir(&tmp)?;
    fs::rename(&tmp, &target)
        .with_context(|| format!("renaming {} to {}", tmp.display(), target.display()))?;
    sync_dir(root)?;
    prune(root, keep)?;
    Ok(target)
}

/// Checkpoint steps under `root`, newest first.
fn list(root: &Path) -> anyhow::Result<Vec<u64>> {
    let mut steps = Vec::new();
    if !root.exists() {
        return Ok(steps);
    }
    for entry in fs::read_dir(root).with_context(|| format!("listing {}", root.display()))? {
        let entry = entry?;
        if let Some(step) = entry
            .file_name()
            .to_str()
            .and_then(|n| n.parse::<u64>().ok())
        {
            if entry.path().is_dir() {
                steps.push(step);
            }
        }
    }
    steps.sort_unstable_by(|a, b| b.cmp(a));
    Ok(steps)
}

fn prune(root: &Path, keep: usize) -> anyhow::Result<()> {
    for step in list(root)?.into_iter().skip(keep) {
        let dir = root.join(step.to_string());
        fs::remove_dir_all(&dir)
            .with_context(|| format!("deleting old checkpoint {}", dir.display()))?;
    }
    Ok(())
}

fn verify(dir: &Path, step: u64) -> anyhow::Result<BTreeMap<String, Vec<u8>>> {
    let manifest: Manifest =
        serde_json::from_slice(&fs::read(dir.join(MANIFEST)).context("reading manifest.json")?)
            .context("parsing manifest.json")?;
    if manifest.step != step {
        bail!(
            "manifest says step {}, directory says {step}",
            manifest.step
        );
    }
    let mut files = BTreeMap::new();
    for entry in manifest.files {
        if entry.name.contains('/') || entry.name.contains("..") {
            bail!(
                "manifest names a file outside the checkpoint: {:?}",
                entry.name
            );
        }
        let bytes =
            fs::read(dir.join(&entry.name)).with_context(|| format!("reading {}", entry.name))?;
        if bytes.len() as u64 != entry.size {
            bail!(
                "{} has {} bytes, manifest says {}",
                entry.name,
                bytes.len(),
                entry.size
            );
        }
        if sha256_hex(&bytes) != entry.sha256 {
            bail!(
                "{} does not match its sha256 in the manifest (corrupted)",
                entry.name
            );
        }
        files.insert(entry.name, bytes);
    }
    Ok(files)
}

/// Loads the newest checkpoint under `root` that verifies. `Ok(None)` if there
/// is none at all; an error if every one is damaged.
pub fn load_newest_valid(root: &Path) -> anyhow::Result<Option<LoadedCheckpoint>> {
    let steps = list(root)?;
    if steps.is_empty() {
        return Ok(None);
    }
    let mut skipped = Vec::new();
    for step in steps {
        let dir = root.join(step.to_string());
        match verify(&dir, step) {
            Ok(files) => {
                return Ok(Some(LoadedCheckpoint {
                    step,
                    dir,
                    files,
                    skipped,
                }))
            }
            Err(e) => skipped.push((dir, format!("{e:#}"))),
        }
    }
    let reasons: Vec<String> = skipped
        .iter()
        .map(|(d, r)| format!("{}: {r}", d.display()))
        .collect();
    bail!(
        "no checkpoint under {} verifies:\n  {}",
        root.display(),
        reasons.join("\n  ")
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn newest_valid_checkpoint_wins_and_a_flipped_byte_falls_back() {
        let root = tempfile::tempdir().unwrap();
        for step in [10u64, 20, 30, 40] {
            write(
                root.path(),
                step,
                &[
                    ("weights.safetensors", &step.to_le_bytes()),
                    ("counters.json", b"{}"),
                ],
                3,
            )
            .unwrap();
        }
        let remaining = list(root.path()).unwrap();
        assert_eq!(remaining, vec![40, 30, 20], "keeps the newest 3");
        let loaded = load_newest_valid(root.path()).unwrap().unwrap();
        assert_eq!(loaded.step, 40);
        assert_eq!(loaded.files["weights.safetensors"], 40u64.to_le_bytes());

        let victim = root.path().join("40/weights.safetensors");
        let mut bytes = fs::read(&victim).unwrap();
        bytes[0] ^= 0x01;
        fs::write(&victim, bytes).unwrap();
        let loaded = load_newest_valid(root.path()).unwrap().unwrap();
        assert_eq!(loaded.step, 30);
        assert_eq!(loaded.skipped.len(), 1);
        assert!(
            loaded.skipped[0].1.contains("sha256"),
            "{:?}",
            loaded.skipped
        );
    }

    #[test]
    fn all_damaged_is_an_error_and_none_is_none() {
        let root = tempfile::tempdir().unwrap();
        assert!(load_newest_valid(root.path()).unwrap().is_none());
        write(root.path(), 1, &[("a", b"x")], 2).unwrap();
        fs::remove_file(root.path().join("1/manifest.json")).unwrap();
        assert!(load_newest_valid(root.path()).is_err());
    }
}
