//! Monocular visual odometry: the [`stage::Stage`] abstraction and the [`tracker::Tracker`].
pub mod ba;
pub mod loops;
pub mod pairs;
pub mod stage;
pub mod tracker;
