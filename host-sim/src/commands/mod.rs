//! The CLI's one composite command: `dncal demo` runs the others' library functions in
//! sequence (each command's work lives in the room of what it is: `analyses::X::run`,
//! `model::sets`, `checks::stream_run`, `checks::bench`...). `main.rs` parses,
//! dispatches, prints and sets the exit code.

pub mod demo;
