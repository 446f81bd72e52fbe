//! Every learner setting with its default, in one serde struct (CleanRL style).
//! Loaded from TOML, overridden by CLI flags, printed at start and saved in
//! the run directory.

use serde::{Deserialize, Serialize};
pub use training::config::{PolicyConfig, UnetConfig};
use training::ppo::PpoConfig;
use transport::TransportConfig;

/// The learner's configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, documented::DocumentedFields)]
#[serde(default, deny_unknown_fields)]
pub struct LearnerConfig {
    /// Address of the HTTP endpoint (`/metrics`, `/api/status`, `/healthz`). Port 0 picks a free port.
    pub http_addr: String,
    /// Seconds without a message after which an actor counts as not alive.
    pub actor_timeout_s: f64,
    /// Write a checkpoint after this many policy updates (0 = never by count).
    pub checkpoint_every_updates: u64,
    /// Write a checkpoint at least this often, in seconds (0 = never by
    /// time): what a learner crash can lose. The first checkpoint comes
    /// with the first update. Each costs a write of 17 MB at 64 px (19 MB
    /// at 128 px) in the receive loop; `keep_checkpoints` bound the disk.
    pub checkpoint_interval_s: f64,
    /// How many checkpoints to keep; older ones are deleted.
    pub keep_checkpoints: usize,
    /// What the actors run and the learner trains (shared with the actors).
    pub task: proto::TaskSpec,
    /// Where the networks train: `cpu` (burn's flex backend) or `gpu` (needs a build with `nets/gpu`).
    pub device: String,
    /// Niceness added to the training threads (PPO, U-Net), 0..=19: with
    /// the actors on this host at the same niceness (`deploy/local.sh
    /// --actor-nice` sets both), training and actors share the CPU as
    /// before while the receive loop runs first, so its buffers overflow
    /// less (src/thread_priority.rs). 0 runs every thread at the process's.
    pub training_nice: i32,
    /// PPO settings.
    pub policy: PolicyConfig,
    /// U-Net settings.
    pub unet: UnetConfig,
    /// Shared-memory transport limits (must match the actors').
    pub transport: TransportConfig,
    /// How the run's actors run (renderer, rooms, robot, device,
    /// environments, data): read by every actor and by `actor evaluate`.
    pub actors: proto::ActorSettings,
    /// Each checkpoint scored on the validation rooms in the background.
    pub validation: ValidationConfig,
}

/// The background validation scorer (`src/validation_scorer.rs`): each new
/// checkpoint's U-Net scored on the validation rooms (FloorPlan221–225) by
/// a process of its own at low priority, so that training never waits for
/// it; the scores go to the history, `/metrics`, TensorBoard and the live
/// page, and `actor evaluate --select` chooses a checkpoint from them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, documented::DocumentedFields)]
#[serde(default, deny_unknown_fields)]
pub struct ValidationConfig {
    /// Views per validation room of each scoring (Table 1; Table 2 tries
    /// every object of the rooms whatever this is). 0 turns the scorer off.
    pub views_per_room: usize,
    /// The program that scores: empty runs the `actor` binary beside the
    /// learner's (tasks with a U-Net only). A program named here runs for
    /// every task, as `PROGRAM evaluate --run-dir DIR --step S --scenes val
    /// --views-per-scene N --seed SEED --scores FILE`, and must write the scores
    /// (`proto::ValidationScores` as JSON) to FILE.
    pub scorer: String,
    /// Seed of the validation views (`actor evaluate --seed`): scores
    /// taken with the same seed are of the same views.
    pub seed: u64,
    /// Niceness of the scorer's process, 0..=19 (19: it runs only on
    /// otherwise idle cores).
    pub nice: i32,
}

impl Default for ValidationConfig {
    fn default() -> Self {
        Self {
            views_per_room: 20,
            scorer: String::new(),
            seed: 0,
            nice: 19,
        }
    }
}

impl Default for LearnerConfig {
    fn default() -> Self {
        Self {
            http_addr: "127.0.0.1:9464".into(),
            actor_timeout_s: 10.0,
            checkpoint_every_updates: 10_000,
            checkpoint_interval_s: 120.0,
            keep_checkpoints: 3,
            task: proto::TaskSpec::default(),
            device: "cpu".into(),
            training_nice: 0,
            policy: PolicyConfig::default(),
            unet: UnetConfig::default(),
            transport: TransportConfig::default(),
            actors: proto::ActorSettings::default(),
            validation: ValidationConfig::default(),
        }
    }
}

impl LearnerConfig {
    /// The config to resume a run with: `given` (from `--config` and flags:
    /// checkpoint cadence, learning rates and the like may change on resume)
    /// with the run's `saved` `[task]` and seed, which its checkpoints were
    /// made for. Returns what `given` tried to change of those, so the
    /// caller can say it was ignored; a resume can never turn a run into
    /// another (its networks would not load, and its `config.toml` would
    /// stop describing it).
    pub fn for_resume(mut self, saved: &Self) -> (Self, Vec<&'static str>) {
        let mut ignored = Vec::new();
        if self.task != saved.task {
            ignored.push("[task]");
            self.task = saved.task.clone();
        }
        if self.policy.seed != saved.policy.seed {
            ignored.push("[policy] seed");
            self.policy.seed = saved.policy.seed;
        }
        (self, ignored)
    }

    /// Reads a TOML file; unknown keys are errors so typos never pass silently.
    pub fn from_toml_file(path: &std::path::Path) -> anyhow::Result<Self> {
        Self::from_toml_file_with(Some(path), &[])
    }

    /// Reads a TOML file (or the defaults, for `None`) with `KEY=VALUE`
    /// settings on top (`--set policy.batch_steps=1024`, `--set
    /// actors.renderer=cpu`): a dotted key names a table's entry; a value is
    /// TOML (`1024`, `true`, `"text"`, `[1, 2]`), and what is not TOML is a
    /// string. Unknown keys are errors, as in a file.
    pub fn from_toml_file_with(
        path: Option<&std::path::Path>,
        settings: &[String],
    ) -> anyhow::Result<Self> {
        use anyhow::Context;
        let text = match path {
            Some(path) => std::fs::read_to_string(path)
                .with_context(|| format!("reading learner config {}", path.display()))?,
            None => String::new(),
        };
        let source = path.map_or("the defaults".to_string(), |p| p.display().to_string());
        Self::from_toml_str_with(&text, &source, settings)
    }

    /// [`Self::from_toml_file_with`] on the text of a config; `source`
    /// names where it came from in errors.
    pub fn from_toml_str_with(
        text: &str,
        source: &str,
        settings: &[String],
    ) -> anyhow::Result<Self> {
        use anyhow::Context;
        let mut table: toml::Table = toml::from_str(text).with_context(|| {
            format!("parsing learner config {source} (run `learner print-config` for every key and its default)")
        })?;
        for setting in settings {
            set_dotted(&mut table, setting)?;
        }
        nest_flat_ppo_keys(&mut table)?;
        toml::Value::Table(table).try_into().with_context(|| {
            format!(
                "the learner config from {source} with {settings:?} (run `learner print-config` \
                 for every key and its default)"
            )
        })
    }

    /// The config as TOML text.
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_else(|e| format!("# could not render config: {e}"))
    }

    /// Checks values that would make the learner misbehave.
    pub fn validate(&self) -> anyhow::Result<()> {
        self.task.validate()?;
        self.actors.validate()?;
        self.device
            .parse::<nets::device::DeviceChoice>()
            .map_err(|e| anyhow::anyhow!("device: {e}"))?;
        let p = &self.policy;
        if let Some(device) = &p.device {
            device
                .parse::<nets::device::DeviceChoice>()
                .map_err(|e| anyhow::anyhow!("policy.device: {e}"))?;
        }
        anyhow::ensure!(p.batch_steps >= 1, "policy.batch_steps must be >= 1");
        anyhow::ensure!(p.queue_batches >= 1, "policy.queue_batches must be >= 1");
        let ppo = &p.ppo;
        anyhow::ensure!(
            ppo.epochs >= 1 && ppo.minibatches >= 1 && ppo.minibatches <= p.batch_steps,
            "policy.ppo.epochs must be >= 1 and policy.ppo.minibatches in 1..=policy.batch_steps"
        );
        anyhow::ensure!(
            ppo.learning_rate > 0.0 && ppo.clip > 0.0 && ppo.max_grad_norm > 0.0,
            "policy.ppo.learning_rate, policy.ppo.clip and policy.ppo.max_grad_norm must be > 0"
        );
        let u = &self.unet;
        if let Some(share) = u.class_balance.positive_share() {
            anyhow::ensure!(
                share > 0.0 && share < 1.0,
                "unet.class_balance's positive-share must be above 0 and below 1, got {share}"
            );
        }
        anyhow::ensure!(
            u.batch_frames >= 1 && u.max_uses >= 1 && u.max_frames >= 1,
            "unet.batch_frames, unet.max_uses and unet.max_frames must be >= 1"
        );
        anyhow::ensure!(
            u.hold_actors_beyond_episodes < training::config::MAX_OWED_EPISODES,
            "unet.hold_actors_beyond_episodes must be below {} (the debt the U-Net may owe at \
             all; 0 never holds the actors back), got {}",
            training::config::MAX_OWED_EPISODES,
            u.hold_actors_beyond_episodes
        );
        anyhow::ensure!(
            u.validation_fraction >= 0.0
                && u.test_fraction >= 0.0
                && u.validation_fraction + u.test_fraction < 1.0,
            "unet.validation_fraction + unet.test_fraction must be in 0..1"
        );
        anyhow::ensure!(
            (0.0..1.0).contains(&u.rare_positive_share),
            "unet.rare_positive_share must be in 0..1 (0: the cap drops every frame oldest \
             first), got {}",
            u.rare_positive_share
        );
        anyhow::ensure!(
            (0.0..1.0).contains(&u.weight_average),
            "unet.weight_average must be in 0..1 (the share of the average each step keeps; 0 \
             deploys the latest weights), got {}",
            u.weight_average
        );
        anyhow::ensure!(self.keep_checkpoints >= 1, "keep_checkpoints must be >= 1");
        anyhow::ensure!(
            self.transport.max_actors >= 1,
            "transport.max_actors must be >= 1"
        );
        anyhow::ensure!(self.actor_timeout_s > 0.0, "actor_timeout_s must be > 0");
        anyhow::ensure!(
            (0..=19).contains(&self.training_nice),
            "training_nice must be in 0..=19 (0: training at the receive loop's priority)"
        );
        anyhow::ensure!(
            (0..=19).contains(&self.validation.nice),
            "validation.nice must be in 0..=19"
        );
        Ok(())
    }
}

/// Moves PPO's settings written directly in `[policy]` (configs before
/// 2026-11-29, `--set policy.epochs=2`) into `[policy.ppo]`, where a
/// setting of the old place wins over one of the new (a `--set` on top of a
/// file).
fn nest_flat_ppo_keys(table: &mut toml::Table) -> anyhow::Result<()> {
    use documented::DocumentedFields;
    let Some(policy) = table.get_mut("policy").and_then(toml::Value::as_table_mut) else {
        return Ok(());
    };
    let flat: Vec<String> = policy
        .keys()
        .filter(|key| PpoConfig::get_field_docs(key.as_str()).is_ok())
        .cloned()
        .collect();
    let moved: Vec<(String, toml::Value)> = flat
        .into_iter()
        .filter_map(|key| Some((key.clone(), policy.remove(&key)?)))
        .collect();
    if moved.is_empty() {
        return Ok(());
    }
    policy
        .entry("ppo")
        .or_insert_with(|| toml::Value::Table(toml::Table::new()))
        .as_table_mut()
        .ok_or_else(|| anyhow::anyhow!("policy.ppo is a value, not a table"))?
        .extend(moved);
    Ok(())
}

/// Applies one `KEY=VALUE` setting to a TOML table (see
/// [`LearnerConfig::from_toml_file_with`]).
fn set_dotted(table: &mut toml::Table, setting: &str) -> anyhow::Result<()> {
    let Some((key, raw)) = setting.split_once('=') else {
        anyhow::bail!("--set {setting:?}: expected KEY=VALUE, e.g. policy.batch_steps=1024");
    };
    let path: Vec<&str> = key.trim().split('.').collect();
    anyhow::ensure!(
        path.iter().all(|p| !p.is_empty()),
        "--set {setting:?}: the key {key:?} has an empty part"
    );
    let value = toml::from_str::<toml::Table>(&format!("v = {raw}"))
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(raw.to_string()));
    let (last, parents) = path.split_last().expect("at least one part");
    let mut at = table;
    for part in parents {
        let entry = at
            .entry(part.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        at = entry
            .as_table_mut()
            .ok_or_else(|| anyhow::anyhow!("--set {setting:?}: {part} is a value, not a table"))?;
    }
    at.insert(last.to_string(), value);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nets::unet::ClassBalance;

    #[test]
    fn ppo_settings_of_the_old_flat_policy_table_are_read_into_policy_ppo() {
        // A config.toml from before [policy.ppo]: every field still reaches
        // the update (each changed from its default).
        let mut text = String::from("[policy]\n");
        text.push_str(
            "learning_rate = 0.5\nadam_eps = 0.25\nclip = 0.125\nclip_value_loss = false\n",
        );
        text.push_str("epochs = 7\nminibatches = 3\nvalue_coef = 0.75\nentropy_coef = 0.0625\n");
        text.push_str(
            "max_grad_norm = 9.0\ngamma = 0.5\ngae_lambda = 0.25\nnormalize_advantages = false\n",
        );
        let config = LearnerConfig::from_toml_str_with(&text, "a test", &[]).unwrap();
        let expected = PpoConfig {
            learning_rate: 0.5,
            adam_eps: 0.25,
            clip: 0.125,
            clip_value_loss: false,
            epochs: 7,
            minibatches: 3,
            value_coef: 0.75,
            entropy_coef: 0.0625,
            max_grad_norm: 9.0,
            gamma: 0.5,
            gae_lambda: 0.25,
            normalize_advantages: false,
        };
        assert_eq!(config.policy.ppo, expected);
        // The same in its new place, and written back there.
        let nested = text.replace("[policy]", "[policy.ppo]");
        let config = LearnerConfig::from_toml_str_with(&nested, "a test", &[]).unwrap();
        assert_eq!(config.policy.ppo, expected);
        assert!(config.to_toml().contains("[policy.ppo]"));
        // A setting of the old place on top of a file of the new wins.
        let over =
            LearnerConfig::from_toml_str_with(&nested, "a test", &["policy.epochs=2".into()])
                .unwrap();
        assert_eq!(over.policy.ppo.epochs, 2);
        let typo = LearnerConfig::from_toml_str_with("[policy.ppo]\nepoch = 2\n", "a test", &[]);
        assert!(
            typo.is_err(),
            "unknown keys are refused in the new table too"
        );
    }

    #[test]
    fn settings_on_the_command_line_go_where_their_keys_say() {
        let set = |s: &[&str]| {
            LearnerConfig::from_toml_file_with(
                None,
                &s.iter().map(|s| s.to_string()).collect::<Vec<_>>(),
            )
        };
        let config = set(&[
            "policy.batch_steps=1024",
            "actors.renderer=cpu",
            "actors.data=/data/x y",
            "task.affordances=[\"push\"]",
            "keep_checkpoints = 5",
        ])
        .unwrap();
        assert_eq!(config.policy.batch_steps, 1024);
        assert_eq!(config.actors.renderer, "cpu");
        assert_eq!(config.actors.data.as_deref(), Some("/data/x y"));
        assert_eq!(config.task.affordances, vec![proto::Affordance::Push]);
        assert_eq!(config.keep_checkpoints, 5);
        let share = set(&["unet.class_balance={positive-share = 0.25}"]).unwrap();
        assert_eq!(share.unet.class_balance, ClassBalance::PositiveShare(0.25));
        assert!(toml::from_str::<LearnerConfig>(&share.to_toml()).unwrap() == share);
        for (bad, says) in [
            ("policy.batch_step=3", "batch_step"),
            ("no_equals_sign", "KEY=VALUE"),
            ("policy..seed=1", "empty part"),
            ("keep_checkpoints.x=1", "keep_checkpoints"),
        ] {
            let err = format!("{:#}", set(&[bad]).unwrap_err());
            assert!(err.contains(says), "{bad}: {err}");
        }
        let err = format!(
            "{:#}",
            set(&["policy.seed=1", "policy.seed.x=2"]).unwrap_err()
        );
        assert!(err.contains("not a table"), "{err}");
        let file = std::env::temp_dir().join(format!("afx-set-{}.toml", std::process::id()));
        std::fs::write(&file, "[policy]\nbatch_steps = 7\nepochs = 2\n").unwrap();
        let over = LearnerConfig::from_toml_file_with(
            Some(file.as_path()),
            &["policy.batch_steps=9".to_string()],
        )
        .unwrap();
        assert_eq!((over.policy.batch_steps, over.policy.ppo.epochs), (9, 2));
        std::fs::remove_file(&file).ok();
    }

    #[test]
    fn defaults_survive_a_toml_round_trip_and_typos_are_refused() {
        let config = LearnerConfig::default();
        assert_eq!(
            toml::from_str::<LearnerConfig>(&config.to_toml()).unwrap(),
            config
        );
        assert!(toml::from_str::<LearnerConfig>("actor_timeout = 3").is_err());
        let partial: LearnerConfig =
            toml::from_str("[policy]\nbatch_steps = 6\n[task]\nenv = \"bandit-fixture\"").unwrap();
        assert_eq!(partial.policy.batch_steps, 6);
        assert_eq!(partial.policy.ppo.epochs, 4);
        assert_eq!(partial.task.env, proto::EnvKind::BanditFixture);
        let weighted: LearnerConfig = toml::from_str("[task.reward]\nfailure = 0.25").unwrap();
        assert_eq!(weighted.task.reward.failure, 0.25);
        assert_eq!(
            weighted.task.reward.navigation,
            proto::RewardWeights::default().navigation
        );
        assert!(toml::from_str::<LearnerConfig>("[task.reward]\nfail = 1.0").is_err());
        let gru: LearnerConfig = toml::from_str("[task]\nmethod = \"nomap-seg\"").unwrap();
        assert!(gru.validate().is_ok());
        assert!(
            gru.task.labels_background(),
            "on by default where segments are"
        );
        let paper: LearnerConfig = toml::from_str("[task]\nbackground_negative = false").unwrap();
        assert!(
            !paper.task.labels_background(),
            "the paper's rule is one line away"
        );
        let split: LearnerConfig =
            toml::from_str("device = \"gpu\"\n[policy]\ndevice = \"cpu\"").unwrap();
        assert!(split.validate().is_ok());
        assert_eq!(split.policy.device.as_deref(), Some("cpu"));
        assert_eq!(
            toml::from_str::<LearnerConfig>(&split.to_toml()).unwrap(),
            split
        );
        assert!(refusal("[policy]\ndevice = \"cuda\"").contains("policy.device"));
        assert!(refusal("[policy]\nqueue_batches = 0").contains("policy.queue_batches"));
        assert!(refusal("[task]\nmemory_size = 0").contains("task.memory_size"));
    }

    #[test]
    fn a_resume_keeps_the_runs_task_and_seed_and_takes_the_rest() {
        let saved: LearnerConfig =
            toml::from_str("[task]\nmethod = \"nomap-seg\"\nimage_size = 64\n[policy]\nseed = 2")
                .unwrap();
        // A config written for a fresh run: the default task and seed, new checkpoint cadence.
        let given: LearnerConfig =
            toml::from_str("keep_checkpoints = 20\n[task]\nconfidence_after_steps = 5").unwrap();
        let (resumed, ignored) = given.for_resume(&saved);
        assert_eq!(resumed.task, saved.task);
        assert_eq!(resumed.policy.seed, 2);
        assert_eq!(resumed.keep_checkpoints, 20);
        assert_eq!(ignored, vec!["[task]", "[policy] seed"]);
        let (same, ignored) = saved.clone().for_resume(&saved);
        assert_eq!((same, ignored), (saved, Vec::<&str>::new()));
    }

    #[test]
    fn the_shipped_presets_load_and_say_what_they_promise() {
        let preset = |name: &str| {
            let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../configs")
                .join(name);
            let config = LearnerConfig::from_toml_file(&path).unwrap();
            config.validate().unwrap();
            config
        };
        let paper = preset("paper.toml");
        assert_eq!(paper.task.affordances, vec![proto::Affordance::PickUp]);
        assert_eq!(
            (paper.task.image_size, paper.task.episode_steps),
            (128, 600)
        );
        assert!(!paper.task.labels_background());
        assert_eq!(paper.task.confidence_after_steps, 400_000);
        let w = paper.task.reward;
        assert_eq!((w.navigation, w.interaction, w.failure), (1.0, 1.0, 1.0));
        assert!(!paper.task.selection.within_reach, "the paper's grid");
        assert_eq!(
            paper.unet.class_balance,
            nets::unet::ClassBalance::Pixels,
            "the paper's loss"
        );
        assert!(!paper.unet.mirror_frames, "no augmentation in the paper");
        assert!(
            LearnerConfig::default().unet.mirror_frames,
            "the project's default"
        );
        let small = preset("small-cpu.toml");
        assert_eq!((small.task.image_size, small.task.episode_steps), (64, 100));
        let scale = preset("paper-scale.toml");
        assert_eq!(
            (scale.task.image_size, scale.task.episode_steps),
            (128, 600)
        );
        assert_eq!(scale.task.affordances.len(), 2);
        assert_eq!(scale.policy.batch_steps, 1024);
        assert!(scale.task.labels_background());
        let w = scale.task.reward;
        let default = proto::RewardWeights::default();
        assert_eq!(
            (w.navigation, w.interaction, w.failure),
            (0.1, default.interaction, default.failure)
        );
    }

    /// Why `validate` refuses the config `text` parses to.
    fn refusal(text: &str) -> String {
        let config: LearnerConfig = toml::from_str(text).unwrap();
        config.validate().unwrap_err().to_string()
    }
}
