//! A real pseudo-terminal: the simulator holds the master, the host opens the slave path
//! exactly as it would open `/dev/ttyUSB0`.

use std::ffi::CStr;
use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::path::{Path, PathBuf};

pub struct Pty {
    pub master: OwnedFd,
    /// Kept open so the line settings survive the host closing and reopening the port, and
    /// so the master never sees a hang-up between host sessions.
    _slave: OwnedFd,
    pub slave_path: PathBuf,
    link: Option<PathBuf>,
}

fn check(ret: libc::c_int, what: &str) -> io::Result<libc::c_int> {
    if ret < 0 {
        let e = io::Error::last_os_error();
        Err(io::Error::new(e.kind(), format!("{what}: {e}")))
    } else {
        Ok(ret)
    }
}

impl Pty {
    /// Opens a pty pair in raw mode, master non-blocking. With `link`, a symlink to the slave
    /// is made there (replacing an older symlink, never a regular file).
    pub fn open(link: Option<&Path>) -> io::Result<Pty> {
        // SAFETY: plain libc calls on descriptors we own; results are checked.
        unsafe {
            let m = check(
                libc::posix_openpt(libc::O_RDWR | libc::O_NOCTTY | libc::O_CLOEXEC),
                "posix_openpt",
            )?;
            let master = OwnedFd::from_raw_fd(m);
            check(libc::grantpt(m), "grantpt")?;
            check(libc::unlockpt(m), "unlockpt")?;
            let mut name = [0 as libc::c_char; 128];
            let r = libc::ptsname_r(m, name.as_mut_ptr(), name.len());
            if r != 0 {
                return Err(io::Error::from_raw_os_error(r));
            }
            let slave_path =
                PathBuf::from(CStr::from_ptr(name.as_ptr()).to_string_lossy().into_owned());
            let cpath = std::ffi::CString::new(slave_path.as_os_str().as_encoded_bytes()).unwrap();
            let s = check(
                libc::open(
                    cpath.as_ptr(),
                    libc::O_RDWR | libc::O_NOCTTY | libc::O_CLOEXEC,
                ),
                "open pty slave",
            )?;
            let slave = OwnedFd::from_raw_fd(s);
            let mut tio: libc::termios = std::mem::zeroed();
            check(libc::tcgetattr(s, &mut tio), "tcgetattr")?;
            libc::cfmakeraw(&mut tio);
            check(libc::tcsetattr(s, libc::TCSANOW, &tio), "tcsetattr")?;
            let fl = check(libc::fcntl(m, libc::F_GETFL), "fcntl")?;
            check(
                libc::fcntl(m, libc::F_SETFL, fl | libc::O_NONBLOCK),
                "fcntl",
            )?;
            let link = match link {
                Some(l) => {
                    if let Ok(md) = std::fs::symlink_metadata(l) {
                        if !md.file_type().is_symlink() {
                            return Err(io::Error::new(
                                io::ErrorKind::AlreadyExists,
                                format!(
                                    "{} exists and is not a symlink; refusing to replace it",
                                    l.display()
                                ),
                            ));
                        }
                        std::fs::remove_file(l)?;
                    }
                    std::os::unix::fs::symlink(&slave_path, l)?;
                    Some(l.to_path_buf())
                }
                None => None,
            };
            Ok(Pty {
                master,
                _slave: slave,
                slave_path,
                link,
            })
        }
    }

    /// Reads what is available without blocking. `Ok(0)` means nothing to read.
    pub fn read(&self, buf: &mut [u8]) -> io::Result<usize> {
        // SAFETY: buf is valid for buf.len() bytes.
        let n = unsafe { libc::read(self.master.as_raw_fd(), buf.as_mut_ptr().cast(), buf.len()) };
        if n < 0 {
            let e = io::Error::last_os_error();
            if e.kind() == io::ErrorKind::WouldBlock || e.raw_os_error() == Some(libc::EIO) {
                // EIO: no slave open right now (cannot happen while we hold one, but harmless).
                return Ok(0);
            }
            return Err(e);
        }
        Ok(n as usize)
    }

    /// Writes as much as the pty takes; returns the count (0 when its buffer is full).
    pub fn write(&self, buf: &[u8]) -> io::Result<usize> {
        // SAFETY: buf is valid for buf.len() bytes.
        let n = unsafe { libc::write(self.master.as_raw_fd(), buf.as_ptr().cast(), buf.len()) };
        if n < 0 {
            let e = io::Error::last_os_error();
            if e.kind() == io::ErrorKind::WouldBlock {
                return Ok(0);
            }
            return Err(e);
        }
        Ok(n as usize)
    }

    /// Waits up to `timeout_ms` for input.
    pub fn wait_readable(&self, timeout_ms: i32) -> bool {
        let mut p = libc::pollfd {
            fd: self.master.as_raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        };
        // SAFETY: one valid pollfd.
        let r = unsafe { libc::poll(&mut p, 1, timeout_ms) };
        r > 0 && (p.revents & libc::POLLIN) != 0
    }
}

impl Drop for Pty {
    fn drop(&mut self) {
        if let Some(l) = &self.link {
            let _ = std::fs::remove_file(l);
        }
    }
}
