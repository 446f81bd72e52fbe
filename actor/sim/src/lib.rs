//! The project's simulator (AI2-THOR cannot run here): iTHOR living rooms
//! imported from AI2-THOR's object metadata, the room closed by walls, and,
//! in later parts, procedural rooms, physics, robot profiles and rendering.

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
