//! The run's join key on disk: written once by the learner into the run
//! directory, readable by its owner only, and read by every actor it starts.

use std::io::Write;
use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};

use proto::{JoinKey, JOIN_KEY_LEN};

/// The key file's name inside a run directory.
pub const JOIN_KEY_FILE: &str = "join.key";

/// Why a join key file could not be used.
#[derive(Debug, thiserror::Error)]
pub enum JoinKeyFileError {
    /// The file could not be read or written.
    #[error("{action} the join key file {path}: {source}")]
    Io {
        /// What was being done.
        action: &'static str,
        /// The key file.
        path: PathBuf,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// The file's text is not a key.
    #[error("the join key file {path} is damaged ({source}); delete it and restart the learner and its actors")]
    Damaged {
        /// The key file.
        path: PathBuf,
        /// What is wrong with the text.
        source: proto::JoinKeyError,
    },
    /// The operating system gave no random bytes.
    #[error("no random bytes for a join key: {0}")]
    Random(String),
}

/// Reads the key in `path`.
pub fn read_join_key(path: &Path) -> Result<JoinKey, JoinKeyFileError> {
    let text = std::fs::read_to_string(path).map_err(|source| JoinKeyFileError::Io {
        action: "reading",
        path: path.to_path_buf(),
        source,
    })?;
    JoinKey::from_hex(&text).map_err(|source| JoinKeyFileError::Damaged {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads the key in `path`, or makes one from the operating system's random
/// source and writes it there (mode 0600, all at once: an actor never reads
/// half a key). A resumed run keeps its key, so actors that outlive a
/// learner restart can join the new learner.
pub fn load_or_create_join_key(path: &Path) -> Result<JoinKey, JoinKeyFileError> {
    if path.exists() {
        restrict_to_owner(path)?;
        return read_join_key(path);
    }
    let mut bytes = [0u8; JOIN_KEY_LEN];
    getrandom::fill(&mut bytes).map_err(|e| JoinKeyFileError::Random(e.to_string()))?;
    let key = JoinKey::from_bytes(bytes);
    let io = |action| {
        move |source| JoinKeyFileError::Io {
            action,
            path: path.to_path_buf(),
            source,
        }
    };
    let partial = path.with_extension("key.partial");
    let _ = std::fs::remove_file(&partial);
    let mut file = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(0o600)
        .open(&partial)
        .map_err(io("creating"))?;
    writeln!(file, "{}", key.to_hex()).map_err(io("writing"))?;
    file.sync_all().map_err(io("writing"))?;
    std::fs::rename(&partial, path).map_err(io("writing"))?;
    Ok(key)
}

/// Takes group and other permissions off an existing key file.
fn restrict_to_owner(path: &Path) -> Result<(), JoinKeyFileError> {
    let io = |source| JoinKeyFileError::Io {
        action: "restricting",
        path: path.to_path_buf(),
        source,
    };
    let mode = std::fs::metadata(path).map_err(io)?.permissions().mode();
    if mode & 0o077 != 0 {
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode & 0o700))
            .map_err(io)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("afx-join-key-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir.join(JOIN_KEY_FILE)
    }

    #[test]
    fn a_new_key_is_private_and_kept_for_the_next_start() {
        let path = scratch("new");
        let key = load_or_create_join_key(&path).unwrap();
        let mode = std::fs::metadata(&path).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o600);
        assert_eq!(load_or_create_join_key(&path).unwrap(), key);
        assert_eq!(read_join_key(&path).unwrap(), key);
        let other = scratch("other");
        assert_ne!(load_or_create_join_key(&other).unwrap(), key, "random");
    }

    #[test]
    fn a_readable_key_is_restricted_and_a_damaged_one_refused() {
        let path = scratch("loose");
        std::fs::write(&path, format!("{}\n", "ab".repeat(JOIN_KEY_LEN))).unwrap();
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o644)).unwrap();
        load_or_create_join_key(&path).unwrap();
        let mode = std::fs::metadata(&path).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o600);
        std::fs::write(&path, "not a key").unwrap();
        let err = load_or_create_join_key(&path).unwrap_err().to_string();
        assert!(
            err.contains("damaged") && err.contains("delete it"),
            "{err}"
        );
        let missing = read_join_key(&path.with_file_name("absent")).unwrap_err();
        assert!(
            missing.to_string().contains("reading the join key file"),
            "{missing}"
        );
    }
}
