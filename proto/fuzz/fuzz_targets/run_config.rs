//! Fuzzes what an actor reads from a run's config and join key: any text
//! must parse into a task and actor settings that validate, or be refused,
//! never panic.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(task) = toml::from_str::<proto::TaskSpec>(text) {
        if task.validate().is_ok() {
            // A valid task has a layout the policy can be built for.
            let layout = task.layout();
            assert!(layout.n_actions > 0);
        }
    }
    if let Ok(actors) = toml::from_str::<proto::ActorSettings>(text) {
        let _ = actors.validate();
    }
    let _ = proto::JoinKey::from_hex(text);
});
