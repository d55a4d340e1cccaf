//! The simulator's event stream, on its own thread where a core is free for it.

use sim::{SensorEvent, Simulation};

/// The simulator's event stream, with the time spent producing it.
///
/// A run started outside a rayon pool simulates on its own thread, a bounded queue ahead of
/// the pipeline, so the two halves overlap. Inside a pool (Monte Carlo runs, which already
/// fill the cores) it simulates inline: a pool worker blocked on the queue would starve
/// the laser's own rayon tasks and deadlock. The pipeline sees the same event sequence
/// either way.
pub(super) enum EventSource {
    Inline { sim: Box<Simulation>, sim_time: f64 },
    Threaded { events: std::sync::mpsc::Receiver<SensorEvent>, producer: std::thread::JoinHandle<(Simulation, f64)> },
}

impl EventSource {
    /// Starts the stream; a camera thread that cannot start is reported to `warn`, and the
    /// camera then renders on the simulator's thread.
    pub(super) fn start(mut sim: Simulation, warn: &mut dyn FnMut(String)) -> Self {
        if rayon::current_thread_index().is_some() {
            return EventSource::Inline { sim: Box::new(sim), sim_time: 0.0 };
        }
        // A core is free for the physics while the camera renders (see
        // Simulation::render_camera_on_thread); if the thread cannot start, render inline.
        if let Err(e) = sim.render_camera_on_thread() {
            warn(format!("{e}; the camera renders on the simulator's thread"));
        }
        let (tx, events) = std::sync::mpsc::sync_channel::<SensorEvent>(64);
        let producer = std::thread::spawn(move || {
            let mut sim_time = 0.0f64;
            loop {
                let tick = std::time::Instant::now();
                let Some(event) = sim.next_event() else { break };
                sim_time += tick.elapsed().as_secs_f64();
                if tx.send(event).is_err() {
                    break;
                }
            }
            (sim, sim_time)
        });
        EventSource::Threaded { events, producer }
    }

    pub(super) fn next(&mut self) -> Option<SensorEvent> {
        match self {
            EventSource::Inline { sim, sim_time } => {
                let tick = std::time::Instant::now();
                let event = sim.next_event();
                *sim_time += tick.elapsed().as_secs_f64();
                event
            }
            EventSource::Threaded { events, .. } => events.recv().ok(),
        }
    }

    /// The simulator once the stream has ended, and its time (s).
    pub(super) fn finish(self) -> (Simulation, f64) {
        match self {
            EventSource::Inline { sim, sim_time } => (*sim, sim_time),
            EventSource::Threaded { events, producer } => {
                drop(events);
                match producer.join() {
                    Ok(done) => done,
                    Err(panic) => std::panic::resume_unwind(panic),
                }
            }
        }
    }
}
