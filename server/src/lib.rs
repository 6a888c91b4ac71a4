//! `scalpel-server`: the station process. It owns the simulation and the 1 kHz haptic loop
//! (ARCHITECTURE.md): a haptic thread that renders force from the simulation's local force
//! model through the output stage, and a simulation thread that advances the scene with the
//! device's poses. Device I/O, render frames and the network endpoint attach to these.

pub mod command_audit;
pub mod config;
pub mod console;
pub mod device;
pub mod device_monitor;
pub mod faults;
pub mod grid_clock;
pub mod host_check;
pub mod input_file;
pub mod journal;
pub mod lesson_feed;
pub mod net;
pub mod output;
pub mod realtime;
pub mod recut_worker;
pub mod render_frames;
pub mod scene_budget;
pub mod scene_file;
pub mod shm_device;
pub mod sim_pool;
pub mod sim_wake;
pub mod station;
