//! The one thread that owns the stage and the camera for the service's lifetime. Their I/O
//! blocks (serial reads, frame waits), so it stays on this plain thread; the async side sends
//! it [`Command`]s and awaits the replies. The running item is interrupted through
//! [`Control`], which the async side sets directly while this thread is busy: a deferred pause
//! or a stop is seen at the next tile boundary, an immediate pause, an abort or a halt cancel
//! the stage's wait at once (the driver then stops the stages), and a halt resets the
//! controller after that (as Micro-Manager's devices are owned by one core and probe-rs's
//! probe by one session).

use super::devices::{
    png_of, position_json, Control, DeviceError, Devices, Ended, Interrupt, Look, Opener, Ran,
    Settings,
};
use super::events::{Bus, Kind};
use super::queue::{ItemId, Task};
use crate::coords::CarriageUm;
use crate::stage::{StageError, StageStatus};
use serde_json::json;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::Duration;
use tokio::sync::oneshot;

type Reply<T> = oneshot::Sender<Result<T, DeviceError>>;

pub enum Command {
    Status(Reply<StageStatus>),
    Jog {
        delta: CarriageUm,
        reply: Reply<CarriageUm>,
    },
    /// Take a live frame now (idle only).
    Look(Reply<Look>),
    /// Lay the simulator's film on the carriage (true) or lift it off (idle only).
    SimFilm {
        laid: bool,
        reply: Reply<()>,
    },
    /// Run (or continue) an item.
    Run {
        id: ItemId,
        task: Task,
        dir: PathBuf,
        reply: oneshot::Sender<Ran>,
    },
    /// Reset the controller at once (when no item runs; a running item is halted through
    /// [`Control`]).
    Halt(Reply<String>),
    Close(oneshot::Sender<Result<(), String>>),
}

/// The async side's end of the hardware thread.
pub struct Handle {
    tx: mpsc::Sender<Command>,
    /// Held while a command is checked against `busy` and sent, and while an item is handed
    /// over.
    order: Mutex<()>,
    pub control: Arc<Control>,
    /// The id of the item running on the thread (0: none).
    busy: Arc<AtomicU64>,
    /// The newest live frame (or scan tile).
    pub last_look: Arc<Mutex<Option<Look>>>,
    /// The soft limits in force on the stage (the controller's and the operator's).
    pub limits: crate::stage::SoftLimits,
    /// The simulator's film, laid or not ([`Devices::sim_film`]).
    pub sim_film: Option<Arc<AtomicBool>>,
    thread: Mutex<Option<std::thread::JoinHandle<()>>>,
}

impl Handle {
    /// Sends a command; the reply comes on the channel the command carries.
    fn send(&self, c: Command) -> Result<(), DeviceError> {
        self.tx.send(c).map_err(|_| DeviceError::Gone)
    }

    /// Hands item `id` to the thread: busy with it from now on, before the thread takes it up,
    /// so that a question asked meanwhile is refused at once instead of waiting behind the
    /// whole item (a status asked in that moment once waited for a pixel session's 3 s; behind
    /// a scan it would have waited hours).
    pub fn run(
        &self,
        id: ItemId,
        task: Task,
        dir: PathBuf,
        reply: oneshot::Sender<Ran>,
    ) -> Result<(), DeviceError> {
        let _order = self.order.lock().unwrap_or_else(|e| e.into_inner());
        self.busy.store(id + 1, Ordering::SeqCst);
        let sent = self.send(Command::Run {
            id,
            task,
            dir,
            reply,
        });
        if sent.is_err() {
            self.busy.store(0, Ordering::SeqCst);
        }
        sent
    }

    pub fn busy_with(&self) -> Option<ItemId> {
        match self.busy.load(Ordering::SeqCst) {
            0 => None,
            n => Some(n - 1),
        }
    }

    /// Asks a command with a reply and awaits it.
    pub async fn ask<T>(&self, make: impl FnOnce(Reply<T>) -> Command) -> Result<T, DeviceError> {
        let (tx, rx) = oneshot::channel();
        {
            // Checked and sent in one step with respect to [`Handle::run`]: a question is
            // either ahead of an item on the channel or refused.
            let _order = self.order.lock().unwrap_or_else(|e| e.into_inner());
            if let Some(id) = self.busy_with() {
                return Err(DeviceError::Busy(id));
            }
            self.send(make(tx))?;
        }
        rx.await.map_err(|_| DeviceError::Gone)?
    }

    /// Closes the devices and ends the thread.
    pub fn close(&self) -> Result<(), String> {
        let (tx, rx) = oneshot::channel();
        if self.tx.send(Command::Close(tx)).is_err() {
            return Ok(());
        }
        let r = rx.blocking_recv().unwrap_or(Ok(()));
        if let Some(t) = self.thread.lock().unwrap_or_else(|e| e.into_inner()).take() {
            let _ = t.join();
        }
        r
    }
}

/// Starts the hardware thread and opens the devices on it; an error opening them is returned
/// here, before the service takes any request.
pub fn spawn(open: Opener, bus: Arc<Bus>, settings: Settings) -> Result<Handle, String> {
    let cancel = Arc::new(AtomicBool::new(false));
    let control = Arc::new(Control::new(cancel.clone()));
    let busy = Arc::new(AtomicU64::new(0));
    let last_look = Arc::new(Mutex::new(None));
    let (tx, rx) = mpsc::channel();
    let (opened_tx, opened_rx) = mpsc::channel();
    let thread = {
        let (control, busy, last_look) = (control.clone(), busy.clone(), last_look.clone());
        std::thread::Builder::new()
            .name("rig-hardware".into())
            .spawn(move || {
                let sink = {
                    let bus = bus.clone();
                    crate::stage::port::PositionSink(Arc::new(move |p| {
                        bus.position(position_json(p), false)
                    }))
                };
                let dev = match open(cancel, sink) {
                    Ok(d) => {
                        let _ = opened_tx.send(Ok((d.stage.limits(), d.sim_film.clone())));
                        d
                    }
                    Err(e) => {
                        let _ = opened_tx.send(Err(e));
                        return;
                    }
                };
                Actor {
                    dev: Some(dev),
                    control,
                    busy,
                    bus,
                    settings,
                    last_look,
                    looks: 0,
                }
                .serve(rx)
            })
            .map_err(|e| format!("starting the hardware thread: {e}"))?
    };
    let (limits, sim_film) = opened_rx
        .recv()
        .map_err(|_| "the hardware thread ended while opening the devices".to_string())??;
    Ok(Handle {
        order: Mutex::new(()),
        limits,
        sim_film,
        tx,
        control,
        busy,
        last_look,
        thread: Mutex::new(Some(thread)),
    })
}

struct Actor {
    dev: Option<Devices>,
    control: Arc<Control>,
    busy: Arc<AtomicU64>,
    bus: Arc<Bus>,
    settings: Settings,
    last_look: Arc<Mutex<Option<Look>>>,
    looks: u64,
}

/// How often an idle thread reads the stage's position while clients listen.
const IDLE_POLL: Duration = Duration::from_millis(100);

impl Actor {
    fn serve(mut self, rx: mpsc::Receiver<Command>) {
        let mut last: Option<CarriageUm> = None;
        loop {
            let c = match rx.recv_timeout(IDLE_POLL) {
                Ok(c) => c,
                Err(mpsc::RecvTimeoutError::Timeout) => {
                    if self.bus.clients() > 0 {
                        self.poll_position(&mut last);
                    }
                    continue;
                }
                Err(mpsc::RecvTimeoutError::Disconnected) => break,
            };
            let dev = self.dev.as_mut().expect("open until closed");
            match c {
                Command::Status(r) => {
                    let _ = r.send(dev.stage.status().map_err(Into::into));
                }
                Command::Jog { delta, reply } => {
                    let speed = dev.stage.info().max_speed_um_s / 4.0;
                    let r = dev.stage.jog(delta, speed).map_err(Into::into);
                    self.control.take();
                    if let Ok(p) = &r {
                        self.bus.position(position_json(*p), true);
                    }
                    let _ = reply.send(r);
                }
                Command::SimFilm { laid, reply } => {
                    let r = match &dev.sim_film {
                        Some(f) => {
                            f.store(laid, Ordering::SeqCst);
                            *self.last_look.lock().unwrap_or_else(|e| e.into_inner()) = None;
                            Ok(())
                        }
                        None => Err(DeviceError::NotSimulated),
                    };
                    let _ = reply.send(r);
                }
                Command::Look(r) => {
                    let _ = r.send(self.look());
                }
                Command::Run {
                    id,
                    task,
                    dir,
                    reply,
                } => {
                    let ran = super::work::run(
                        &mut super::devices::Rig {
                            dev: self.dev.as_mut().expect("open"),
                            bus: &self.bus,
                            control: &self.control,
                            settings: &self.settings,
                            last_look: &self.last_look,
                        },
                        id,
                        &task,
                        &dir,
                    );
                    let ran = self.settle(ran);
                    self.busy.store(0, Ordering::SeqCst);
                    let _ = reply.send(ran);
                }
                Command::Halt(r) => {
                    self.control.take();
                    let _ = r.send(self.halt().map_err(Into::into));
                }
                Command::Close(r) => {
                    let d = self.dev.take().expect("open");
                    drop(d.stage);
                    drop(d.camera);
                    let _ = r.send((d.close)());
                    return;
                }
            }
        }
        if let Some(d) = self.dev.take() {
            let _ = (d.close)();
        }
    }

    /// Maps a run's end to what the operator asked, resets the controller after a halt, and
    /// leaves every flag clear for the next item.
    fn settle(&mut self, mut ran: Ran) -> Ran {
        let wanted = self.control.take();
        let asked = match (ran.ended, wanted) {
            (Ended::Done, _) | (_, None) => return ran,
            (_, Some(w)) => w,
        };
        ran.ended = match asked {
            Interrupt::Pause | Interrupt::PauseNow => Ended::Paused,
            Interrupt::Stop => Ended::Stopped,
            Interrupt::Abort => Ended::Aborted,
            Interrupt::Halt => {
                match self.halt() {
                    Ok(what) => ran.message = Some(what),
                    Err(e) => {
                        ran.message = Some(format!("the halt's reset was not confirmed: {e}"));
                        self.bus
                            .publish(Kind::Warning, json!({"message": ran.message}));
                    }
                }
                Ended::Halted
            }
        };
        ran
    }

    /// Resets the controller at once; the stage is then unhomed.
    fn halt(&mut self) -> Result<String, StageError> {
        let dev = self.dev.as_mut().expect("open");
        dev.stage.emergency_stop()?;
        let st = dev.stage.status()?;
        self.bus.position(position_json(st.position), true);
        Ok(format!(
            "controller reset; the stage is {} and must be homed",
            if st.homed { "homed" } else { "not homed" }
        ))
    }

    fn poll_position(&mut self, last: &mut Option<CarriageUm>) {
        let dev = self.dev.as_mut().expect("open");
        match dev.stage.status() {
            Ok(st) if Some(st.position) != *last => {
                *last = Some(st.position);
                self.bus.position(position_json(st.position), false);
            }
            Ok(_) => {}
            Err(e) => {
                self.bus.publish(
                    Kind::Warning,
                    json!({"message": format!("reading the stage's position: {e}")}),
                );
            }
        }
    }

    fn look(&mut self) -> Result<Look, DeviceError> {
        let dev = self.dev.as_mut().expect("open");
        let settled = dev.camera.now()?;
        let c = crate::digitise::capture::capture(
            dev.camera.as_mut(),
            self.settings.look_frames,
            true,
            Duration::from_secs(2),
            Some(settled),
            |_| {},
        )?;
        self.looks += 1;
        let look = Look {
            png: Arc::new(png_of(&c.image).map_err(|e| DeviceError::Other(e.to_string()))?),
            number: self.looks,
            size: [c.image.width, c.image.height],
            taken: std::time::Instant::now(),
        };
        *self.last_look.lock().unwrap_or_else(|e| e.into_inner()) = Some(look.clone());
        Ok(look)
    }
}
