//! A photo as the core takes it, from whoever made it (the rig's scans or anyone's images):
//! its pixels, which photo point each pixel shows, the camera's interior orientation, and its
//! geometry without the pixels.

use crate::coords::PixelView;
use crate::geometry::{Interior, PhotoGrid, PixelToPhoto};
use crate::image::ImageF32;

/// A photo as the core takes it, from whoever made it: the image in grey values, which photo
/// point (mm) each pixel shows, and the camera's interior orientation.
#[derive(Debug, Clone)]
pub struct Photo {
    /// The pixels read: the whole image, or [`Photo::view`] of it.
    pub image: ImageF32,
    /// Which photo point each pixel of the whole image shows (its size is the whole image's).
    pub frame: PixelToPhoto,
    pub interior: Interior,
    /// Where `image` lies in the whole image, and how much smaller it was read.
    pub view: crate::coords::PixelView,
}

/// A scan as the hardware side hands it to the core: its image file and which photo point each
/// of its pixels shows; the core reads the pixels it needs (a window, a pyramid level) itself.
#[derive(Debug, Clone)]
pub struct ScanImage {
    pub image: std::path::PathBuf,
    pub frame: PixelToPhoto,
    pub interior: Interior,
}

/// How the core gets a scan from its sidecar: the hardware side's hand-over.
pub type ScanReader<'a> = dyn Fn(&std::path::Path) -> Result<ScanImage, String> + 'a;

/// The grid of a plain image with square pixels of `pixel_mm`, its centre on the photo
/// coordinates' origin: x = (col − (W−1)/2)·p, y = ((H−1)/2 − row)·p at pixel centres.
pub fn centred_grid(width: usize, height: usize, pixel_mm: f64) -> PhotoGrid {
    PhotoGrid {
        corner_mm: [
            -0.5 * width as f64 * pixel_mm,
            0.5 * height as f64 * pixel_mm,
        ],
        step_mm: pixel_mm,
        width,
        height,
    }
}

/// A camera's pixel → photo relation applied to an image of `width × height`.
pub(crate) fn frame_of(
    camera: &crate::matching::project::Camera,
    width: usize,
    height: usize,
) -> Option<PixelToPhoto> {
    match camera.pixel_to_photo {
        Some(p) => PixelToPhoto::from_centre_origin(p, width, height),
        None => Some(centred_grid(width, height, camera.pixel_mm).into()),
    }
}

/// A photo's geometry without its pixels: what the plan needs.
#[derive(Debug, Clone, Copy)]
pub struct PhotoGeometry {
    /// Which photo point each pixel of the whole image shows.
    pub frame: PixelToPhoto,
    pub interior: Interior,
    /// The whole image's size, pixels.
    pub width: usize,
    pub height: usize,
    /// The part of it that was read, and at which level (the matchers see this; their
    /// sensors are seen through it).
    pub view: PixelView,
}

impl Photo {
    pub fn geometry(&self) -> PhotoGeometry {
        PhotoGeometry {
            frame: self.frame,
            interior: self.interior,
            width: self.frame.width,
            height: self.frame.height,
            view: self.view,
        }
    }
}
