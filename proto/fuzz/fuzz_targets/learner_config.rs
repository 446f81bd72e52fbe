//! Fuzzes the learner's config loader (`learner serve --config FILE`): any
//! text must become a config or be refused with an error, never a panic; a
//! config that validates must survive its own TOML (what the learner writes
//! into a run's `config.toml` and reads back on `--resume`).
#![no_main]

use learner::config::LearnerConfig;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(config) = LearnerConfig::from_toml_str_with(text, "fuzz input", &[]) else {
        return;
    };
    if config.validate().is_err() {
        return;
    }
    let written = config.to_toml();
    let again = LearnerConfig::from_toml_str_with(&written, "its own TOML", &[])
        .expect("a valid config's own TOML parses");
    assert_eq!(
        again.to_toml(),
        written,
        "the config changed on a round trip"
    );
});
