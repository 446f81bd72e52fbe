//! The simulator's flags (data, robot, renderer), shared by every
//! subcommand that runs it, with the run's `[actors]` settings as defaults.

use std::path::PathBuf;

use clap::Args;
use sim::renderer::RendererChoice;

/// Where the simulator's data comes from, which robot it simulates and how
/// it renders: the same flags for every subcommand that runs it. Each
/// defaults to the run config's [actors] setting where there is a run
/// config, else to the value named.
#[derive(Args)]
pub(crate) struct SimArgs {
    /// Shared data directory with ithor-livingrooms/ and
    /// ithor-object-types.tsv. Default: [actors] data, else ../shared/data.
    #[arg(long, env = "AFX_DATA")]
    data: Option<PathBuf>,
    /// Robot profile: a shipped name (default, weak-arm) or a TOML file.
    /// Default: [actors] profile, else default.
    #[arg(long)]
    profile: Option<String>,
    /// Renderer: auto (gpu when a Vulkan adapter exists, else cpu), gpu
    /// (wgpu: a GPU or Mesa lavapipe) or cpu (ray casting). Default:
    /// [actors] renderer, else auto.
    #[arg(long)]
    renderer: Option<RendererChoice>,
}

/// [`SimArgs`] with every default filled in.
pub(crate) struct Sim {
    pub(crate) data: PathBuf,
    pub(crate) profile: String,
    pub(crate) renderer: RendererChoice,
}

impl SimArgs {
    /// The flags given, else the run's `[actors]` settings.
    pub(crate) fn resolve(&self, actors: &proto::ActorSettings) -> anyhow::Result<Sim> {
        let renderer = match self.renderer {
            Some(renderer) => renderer,
            None => actors
                .renderer
                .parse()
                .map_err(|e| anyhow::anyhow!("[actors] renderer: {e}"))?,
        };
        Ok(Sim {
            data: self.data.clone().unwrap_or_else(|| {
                PathBuf::from(actors.data.as_deref().unwrap_or("../shared/data"))
            }),
            profile: self
                .profile
                .clone()
                .unwrap_or_else(|| actors.profile.clone()),
            renderer,
        })
    }
}
