//! The camera rendering on a thread of its own (see
//! [`Simulation::render_camera_on_thread`](crate::Simulation::render_camera_on_thread)):
//! the simulator hands it the robot's and the people's poses at each frame's instant and
//! goes on with physics and the laser while the frame renders. Frames come back in the
//! order they were asked for, from the same camera with the same random draws, so the
//! event stream is the one inline rendering gives.

use std::sync::Mutex;
use std::sync::mpsc::{self, Receiver, Sender, TryRecvError};
use std::thread::JoinHandle;

use crate::camera::{CameraError, CameraFrame, CameraSensor, FramePool};
use crate::messages::{PersonState, Pose2D};

struct Request {
    t: f64,
    robot: Pose2D,
    people: Vec<PersonState>,
    regions: Option<Vec<render::Region>>,
}

pub(crate) struct CameraThread {
    requests: Option<Sender<Request>>,
    /// In a mutex only so the simulation stays `Sync` (it is only locked by its owner).
    frames: Mutex<Receiver<Result<CameraFrame, CameraError>>>,
    worker: Option<JoinHandle<()>>,
    adapter: render::AdapterSummary,
    frame_pool: FramePool,
}

impl CameraThread {
    pub(crate) fn start(mut camera: CameraSensor) -> std::io::Result<Self> {
        let adapter = camera.adapter();
        let frame_pool = camera.frame_pool();
        let (requests, inbox) = mpsc::channel::<Request>();
        let (outbox, frames) = mpsc::channel();
        let worker = std::thread::Builder::new().name("camera".into()).spawn(move || {
            for r in inbox {
                if outbox.send(camera.capture_regions(r.t, &r.robot, &r.people, r.regions.as_deref())).is_err() {
                    break;
                }
            }
        })?;
        Ok(CameraThread {
            requests: Some(requests),
            frames: Mutex::new(frames),
            worker: Some(worker),
            adapter,
            frame_pool,
        })
    }

    pub(crate) fn adapter(&self) -> &render::AdapterSummary {
        &self.adapter
    }

    pub(crate) fn frame_pool(&self) -> FramePool {
        self.frame_pool.clone()
    }

    /// Asks for the frame at `t` (only the pixel `regions`, if given).
    pub(crate) fn request(
        &self,
        t: f64,
        robot: Pose2D,
        people: Vec<PersonState>,
        regions: Option<Vec<render::Region>>,
    ) {
        if let Some(requests) = &self.requests {
            // A send fails only when the thread has ended; the next frame() says so.
            let _ = requests.send(Request { t, robot, people, regions });
        }
    }

    /// The oldest frame asked for and not yet taken, if it is rendered.
    pub(crate) fn try_frame(&self) -> Option<Result<CameraFrame, CameraError>> {
        let frames = self.frames.lock().unwrap_or_else(|p| p.into_inner());
        match frames.try_recv() {
            Ok(frame) => Some(frame),
            Err(TryRecvError::Empty) => None,
            Err(TryRecvError::Disconnected) => Some(Err(CameraError::Thread)),
        }
    }

    /// The oldest frame asked for and not yet taken, waiting for it.
    pub(crate) fn frame(&self) -> Result<CameraFrame, CameraError> {
        self.frames.lock().unwrap_or_else(|p| p.into_inner()).recv().unwrap_or(Err(CameraError::Thread))
    }
}

impl Drop for CameraThread {
    fn drop(&mut self) {
        // Closing the request channel ends the thread's loop.
        self.requests.take();
        if let Some(worker) = self.worker.take() {
            let _ = worker.join();
        }
    }
}
