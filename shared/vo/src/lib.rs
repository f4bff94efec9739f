//! Monocular visual odometry: the [`stage::Stage`] abstraction and the [`tracker::Tracker`].
pub mod ba;
pub mod loops;
mod map;
pub mod mapping_solver;
pub mod pairs;
pub mod pipeline;
pub mod stage;
pub mod tracker;
