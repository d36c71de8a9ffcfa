//! Composition roots: each mode wires the pure core to its edges (`fly`, `sim_fast`,
//! `sim_realtime`, `replay`, `plot`, `export`, `lqr`, `gps`), and what the modes share: the
//! flight's two sides as a profile builds them (`flight`), the run folder (`run_dir`) and its
//! streams read a line at a time (`log_lines`), the simulation options (`sim`), the reports
//! (`report`) and the book's reference pages (`reference`).

pub mod campaign;
pub mod commander_report;
pub mod export;
pub mod flight;
pub mod fly;
pub mod gps;
pub mod log_lines;
pub mod lqr;
pub mod noise;
pub mod plot;
pub mod reference;
pub mod replay;
pub mod replay_batch;
pub mod replay_input;
pub mod replay_output;
pub mod report;
pub mod run_dir;
pub mod sim;
pub mod sim_fast;
pub mod sim_paced;
pub mod sim_realtime;
