//! Coordinate types that carry their unit and system (docs/conventions.md), so a
//! carriage position cannot be passed where a photo coordinate is expected.

use serde::{Deserialize, Serialize};
use std::ops::{Add, Sub};

/// A point in carriage (stage) coordinates, micrometres, 0..travel on each axis.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct CarriageUm {
    pub x: f64,
    pub y: f64,
}

impl CarriageUm {
    pub const fn new(x: f64, y: f64) -> Self {
        CarriageUm { x, y }
    }

    pub fn from_mm(x_mm: f64, y_mm: f64) -> Self {
        CarriageUm {
            x: x_mm * 1000.0,
            y: y_mm * 1000.0,
        }
    }

    pub fn x_mm(self) -> f64 {
        self.x / 1000.0
    }

    pub fn y_mm(self) -> f64 {
        self.y / 1000.0
    }

    /// Axis 0 is X, 1 is Y.
    pub fn axis(self, k: usize) -> f64 {
        if k == 0 {
            self.x
        } else {
            self.y
        }
    }

    pub fn with_axis(mut self, k: usize, v: f64) -> Self {
        if k == 0 {
            self.x = v
        } else {
            self.y = v
        }
        self
    }

    pub fn norm(self) -> f64 {
        self.x.hypot(self.y)
    }
}

impl Add for CarriageUm {
    type Output = CarriageUm;
    fn add(self, o: CarriageUm) -> CarriageUm {
        CarriageUm::new(self.x + o.x, self.y + o.y)
    }
}

impl Sub for CarriageUm {
    type Output = CarriageUm;
    fn sub(self, o: CarriageUm) -> CarriageUm {
        CarriageUm::new(self.x - o.x, self.y - o.y)
    }
}

impl std::fmt::Display for CarriageUm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "({:.4}, {:.4}) mm", self.x_mm(), self.y_mm())
    }
}

/// A point in an image, pixels, with the origin at the top-left corner of the top-left pixel:
/// pixel (c, r) covers [c, c+1) × [r, r+1), so its centre is (c + 0.5, r + 0.5). The same
/// convention as the simulator's truth and GDAL's, so centres compare without a half-pixel
/// shift.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct PixelXY {
    pub col: f64,
    pub row: f64,
}

impl PixelXY {
    pub const fn new(col: f64, row: f64) -> Self {
        PixelXY { col, row }
    }

    pub fn dist(self, o: PixelXY) -> f64 {
        (self.col - o.col).hypot(self.row - o.row)
    }
}

/// A point in photo coordinates, millimetres, origin at the fiducial centre (the camera
/// certificate's system).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct PhotoMm {
    pub x: f64,
    pub y: f64,
}

impl PhotoMm {
    pub const fn new(x: f64, y: f64) -> Self {
        PhotoMm { x, y }
    }
}

/// A point of the object (ground), metres: X east, Y north, Z up, in the project's local
/// system.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct GroundM {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

impl GroundM {
    pub const fn new(x: f64, y: f64, z: f64) -> Self {
        GroundM { x, y, z }
    }
}

/// A rectangle of an image's whole pixels: columns `col0 … col0 + width − 1`, rows
/// `row0 … row0 + height − 1`. A photo read through a window keeps its pixels there; its
/// sensor is shifted by (`col0`, `row0`) so that both speak of the same pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct PixelWindow {
    pub col0: usize,
    pub row0: usize,
    pub width: usize,
    pub height: usize,
}

impl PixelWindow {
    /// The whole of a `width × height` image.
    pub fn whole(width: usize, height: usize) -> PixelWindow {
        PixelWindow {
            col0: 0,
            row0: 0,
            width,
            height,
        }
    }

    /// Whether it starts at (0, 0) and spans `width × height`.
    pub fn is_whole(&self, width: usize, height: usize) -> bool {
        *self == PixelWindow::whole(width, height)
    }
}

/// What of an image was read, and how much smaller: `window` of it averaged over blocks of
/// `factor` × `factor` pixels (1: as it is). The read pixel (c, r) covers the image's
/// [col0 + c·f, col0 + (c + 1)·f) × [row0 + r·f, row0 + (r + 1)·f), so a point at read
/// coordinates (x, y) is at (col0 + f·x, row0 + f·y) in the image's (the core keeps pixel c
/// over [c, c + 1): see docs/conventions.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct PixelView {
    pub window: PixelWindow,
    pub factor: usize,
}

impl PixelView {
    /// The whole of a `width × height` image, as it is.
    pub fn whole(width: usize, height: usize) -> PixelView {
        PixelView {
            window: PixelWindow::whole(width, height),
            factor: 1,
        }
    }

    /// Whether it is the whole of a `width × height` image, as it is.
    pub fn is_whole(&self, width: usize, height: usize) -> bool {
        self.factor == 1 && self.window.is_whole(width, height)
    }

    /// The image's pixels a read pixel spans a side (a factor of 0 is taken as 1).
    pub fn scale(&self) -> f64 {
        self.factor.max(1) as f64
    }

    /// The size of what was read, pixels (a last partial block is left out).
    pub fn size(&self) -> (usize, usize) {
        let f = self.factor.max(1);
        (self.window.width / f, self.window.height / f)
    }

    /// The image's coordinates of read coordinates (x, y).
    pub fn to_image(&self, x: f64, y: f64) -> (f64, f64) {
        let f = self.scale();
        (
            self.window.col0 as f64 + f * x,
            self.window.row0 as f64 + f * y,
        )
    }

    /// The read coordinates of the image's (x, y).
    pub fn to_read(&self, x: f64, y: f64) -> (f64, f64) {
        let f = self.scale();
        (
            (x - self.window.col0 as f64) / f,
            (y - self.window.row0 as f64) / f,
        )
    }
}
