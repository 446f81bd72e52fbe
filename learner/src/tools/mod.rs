//! The learner's offline tools, apart from the service: they read a run's
//! files (`plot`: training curves; `summary`: repeats' figures, with
//! `tries_table` its table of the objects tried; `train_unet`: the
//! U-Net trained offline on the label ladder's dataset) or measure
//! the learner on this machine (`bench_capacity`: what the learner takes
//! from synthetic actors; `bench_transport`: the shared-memory transport).

pub mod bench_capacity;
pub mod bench_transport;
pub mod plot;
pub mod summary;
pub mod train_unet;
pub mod tries_table;
