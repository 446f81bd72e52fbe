//! The project's simulator (AI2-THOR cannot run here): the iTHOR living
//! rooms imported from AI2-THOR's object metadata (`ithor`) and closed by
//! walls, procedural rooms (`procgen`), rapier physics for what is pushed,
//! dropped or carried (`physics`), robot profiles (`profile`) and the
//! agent's navigation and interactions under them (`agent`), ground-truth
//! affordances (`affordances`), and rendering of RGB, depth and instance
//! ids by wgpu or by CPU ray casting (`renderer`, `gpu`, `raycast`).

pub mod affordances;
pub mod agent;
pub mod catalogue;
pub mod geometry;
pub mod gpu;
pub mod ithor;
pub mod mesh;
pub mod physics;
pub mod procgen;
pub mod profile;
pub mod randomise;
pub mod raycast;
pub mod renderer;
pub mod scene;
pub mod scenes;
pub mod script;
pub mod shapes;
pub mod texture;
