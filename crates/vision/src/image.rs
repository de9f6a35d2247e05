//! Grey images with a row stride, loading through the `image` crate (decoding only).

use std::path::Path;

/// Errors of image loading and construction.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// The file could not be opened or read (missing, unreadable).
    #[error("cannot read image {path}: {source}")]
    Io {
        /// The file that failed.
        path: String,
        /// The system's error.
        #[source]
        source: std::io::Error,
    },
    /// The file could not be decoded (corrupt, truncated, unsupported format).
    #[error("cannot decode image {path}: {source}")]
    Decode {
        /// The file that failed.
        path: String,
        /// The decoder's error.
        #[source]
        source: ::image::ImageError,
    },
    /// The image has zero width or height.
    #[error("image {path} is empty ({width}×{height})")]
    Empty {
        /// The offending file (or `<memory>`).
        path: String,
        /// Width in pixels.
        width: usize,
        /// Height in pixels.
        height: usize,
    },
    /// A buffer does not hold `stride·(height−1) + width` elements, or `stride < width`.
    #[error("buffer of {len} elements does not fit {width}×{height} with stride {stride}")]
    BadBuffer {
        /// Buffer length.
        len: usize,
        /// Width in pixels.
        width: usize,
        /// Height in pixels.
        height: usize,
        /// Row stride in elements.
        stride: usize,
    },
    /// The image is too small for the requested operation.
    #[error("image of {width}×{height} is too small: {what}")]
    TooSmall {
        /// Width in pixels.
        width: usize,
        /// Height in pixels.
        height: usize,
        /// What needed more pixels.
        what: String,
    },
    /// Two images that must have the same size do not.
    #[error("image sizes differ: {0}×{1} vs {2}×{3}")]
    SizeMismatch(usize, usize, usize, usize),
}

/// A single-channel image of pixels `T` stored row by row with a row stride (in elements).
///
/// Pixel `(u, v)` (column `u`, row `v`, origin top-left) is `data[v·stride + u]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Image<T> {
    width: usize,
    height: usize,
    stride: usize,
    data: Vec<T>,
}

/// An 8-bit grey image.
pub type GrayImage = Image<u8>;
/// A floating-point grey image (intensities in the same 0–255 scale as [`GrayImage`] unless
/// stated otherwise).
pub type GrayImageF32 = Image<f32>;

impl<T: Copy + Default> Image<T> {
    /// A `width×height` image filled with `T::default()` (stride = width).
    pub fn new(width: usize, height: usize) -> Self {
        Self::filled(width, height, T::default())
    }

    /// A `width×height` image filled with `value` (stride = width).
    pub fn filled(width: usize, height: usize, value: T) -> Self {
        Self {
            width,
            height,
            stride: width,
            data: vec![value; width * height],
        }
    }

    /// Wraps a buffer; fails unless `stride ≥ width` and the buffer holds
    /// `stride·(height − 1) + width` elements (or more).
    pub fn from_vec(
        width: usize,
        height: usize,
        stride: usize,
        data: Vec<T>,
    ) -> Result<Self, ImageError> {
        let needed = if height == 0 {
            0
        } else {
            stride * (height - 1) + width
        };
        if stride < width || data.len() < needed {
            return Err(ImageError::BadBuffer {
                len: data.len(),
                width,
                height,
                stride,
            });
        }
        Ok(Self {
            width,
            height,
            stride,
            data,
        })
    }

    /// Builds an image by evaluating `f(u, v)` at every pixel.
    pub fn from_fn(width: usize, height: usize, mut f: impl FnMut(usize, usize) -> T) -> Self {
        let mut data = Vec::with_capacity(width * height);
        for v in 0..height {
            for u in 0..width {
                data.push(f(u, v));
            }
        }
        Self {
            width,
            height,
            stride: width,
            data,
        }
    }

    /// Width in pixels.
    #[inline]
    pub fn width(&self) -> usize {
        self.width
    }
    /// Height in pixels.
    #[inline]
    pub fn height(&self) -> usize {
        self.height
    }
    /// Row stride in elements.
    #[inline]
    pub fn stride(&self) -> usize {
        self.stride
    }
    /// True if the image has no pixels.
    pub fn is_empty(&self) -> bool {
        self.width == 0 || self.height == 0
    }
    /// The raw buffer (rows separated by `stride`).
    #[inline]
    pub fn data(&self) -> &[T] {
        &self.data
    }
    /// The raw mutable buffer.
    #[inline]
    pub fn data_mut(&mut self) -> &mut [T] {
        &mut self.data
    }
    /// Row `v` (its `width` pixels).
    #[inline]
    pub fn row(&self, v: usize) -> &[T] {
        &self.data[v * self.stride..v * self.stride + self.width]
    }
    /// Mutable row `v`.
    #[inline]
    pub fn row_mut(&mut self, v: usize) -> &mut [T] {
        let s = self.stride;
        let w = self.width;
        &mut self.data[v * s..v * s + w]
    }
    /// Pixel `(u, v)`; panics if out of bounds (use [`get_checked`](Self::get_checked) for
    /// untrusted coordinates).
    #[inline]
    pub fn get(&self, u: usize, v: usize) -> T {
        debug_assert!(u < self.width && v < self.height);
        self.data[v * self.stride + u]
    }
    /// Pixel `(u, v)` or `None` outside the image.
    #[inline]
    pub fn get_checked(&self, u: i64, v: i64) -> Option<T> {
        if u < 0 || v < 0 || u as usize >= self.width || v as usize >= self.height {
            None
        } else {
            Some(self.data[v as usize * self.stride + u as usize])
        }
    }
    /// Sets pixel `(u, v)`.
    #[inline]
    pub fn set(&mut self, u: usize, v: usize, value: T) {
        debug_assert!(u < self.width && v < self.height);
        self.data[v * self.stride + u] = value;
    }
    /// Applies `f` to every pixel into a new image of another type.
    pub fn map<S: Copy + Default>(&self, mut f: impl FnMut(T) -> S) -> Image<S> {
        Image::from_fn(self.width, self.height, |u, v| f(self.get(u, v)))
    }
    /// True if `(u, v)` (real-valued) is at least `margin` pixels inside the image border,
    /// i.e. `margin ≤ u ≤ width − 1 − margin` and the same for `v`.
    #[inline]
    pub fn contains_with_margin(&self, u: f64, v: f64, margin: f64) -> bool {
        u >= margin
            && v >= margin
            && u <= self.width as f64 - 1.0 - margin
            && v <= self.height as f64 - 1.0 - margin
    }
}

impl GrayImage {
    /// Converts to `f32` intensities (same 0–255 scale).
    pub fn to_f32(&self) -> GrayImageF32 {
        let mut data = Vec::with_capacity(self.width * self.height);
        for v in 0..self.height {
            data.extend(self.row(v).iter().map(|&p| p as f32));
        }
        Image {
            width: self.width,
            height: self.height,
            stride: self.width,
            data,
        }
    }
}

fn check_size(path: &str, width: usize, height: usize) -> Result<(), ImageError> {
    if width == 0 || height == 0 {
        return Err(ImageError::Empty {
            path: path.to_owned(),
            width,
            height,
        });
    }
    Ok(())
}

fn decode(path: &Path) -> Result<::image::DynamicImage, ImageError> {
    let name = path.display().to_string();
    let io = |e| ImageError::Io {
        path: name.clone(),
        source: e,
    };
    let reader = ::image::ImageReader::open(path)
        .map_err(io)?
        .with_guessed_format()
        .map_err(io)?;
    let img = reader.decode().map_err(|e| ImageError::Decode {
        path: name.clone(),
        source: e,
    })?;
    check_size(&name, img.width() as usize, img.height() as usize)?;
    Ok(img)
}

/// Decodes an in-memory encoded image (PNG, JPEG, PNM) to 8-bit grey; colour is converted with
/// the Rec. 601 luma weights of the `image` crate, 16-bit images are scaled by `1/257`.
pub fn decode_gray_u8(bytes: &[u8]) -> Result<GrayImage, ImageError> {
    let img = ::image::load_from_memory(bytes).map_err(|e| ImageError::Decode {
        path: "<memory>".into(),
        source: e,
    })?;
    check_size("<memory>", img.width() as usize, img.height() as usize)?;
    let g = img.into_luma8();
    let (w, h) = (g.width() as usize, g.height() as usize);
    Image::from_vec(w, h, w, g.into_raw())
}

/// Loads an image file (PNG 8/16-bit, JPEG, PGM) as 8-bit grey. Colour is converted to luma,
/// 16-bit data are scaled to 8 bit (`v/257`). Empty images and undecodable files are errors
/// naming the file.
pub fn load_gray_u8(path: impl AsRef<Path>) -> Result<GrayImage, ImageError> {
    let img = decode(path.as_ref())?;
    let g = img.into_luma8();
    let (w, h) = (g.width() as usize, g.height() as usize);
    Image::from_vec(w, h, w, g.into_raw())
}

/// Loads an image file as `f32` grey in the 0–255 scale; 16-bit files keep their full precision
/// (`v/257`).
pub fn load_gray_f32(path: impl AsRef<Path>) -> Result<GrayImageF32, ImageError> {
    let img = decode(path.as_ref())?;
    let g = img.into_luma16();
    let (w, h) = (g.width() as usize, g.height() as usize);
    let data = g.into_raw().into_iter().map(|p| p as f32 / 257.0).collect();
    Image::from_vec(w, h, w, data)
}

/// Loads a single-channel 16-bit image unchanged (e.g. a depth map in millimetres, TUM/7-Scenes
/// convention). 8-bit files are widened (`v·257`) by the decoder; use this only for 16-bit data.
pub fn load_u16(path: impl AsRef<Path>) -> Result<Image<u16>, ImageError> {
    let img = decode(path.as_ref())?;
    let g = img.into_luma16();
    let (w, h) = (g.width() as usize, g.height() as usize);
    Image::from_vec(w, h, w, g.into_raw())
}

/// Loads an RGB image (8-bit per channel) as three planes `[r, g, b]`.
pub fn load_rgb_planes(path: impl AsRef<Path>) -> Result<[GrayImage; 3], ImageError> {
    let img = decode(path.as_ref())?.into_rgb8();
    let (w, h) = (img.width() as usize, img.height() as usize);
    let raw = img.into_raw();
    // One pass over the interleaved pixels (a per-pixel closure with index arithmetic took
    // ~4 ms per 640×480 frame of the reader's time, on the core tracking shares).
    let (mut r, mut g, mut b) = (
        Vec::with_capacity(w * h),
        Vec::with_capacity(w * h),
        Vec::with_capacity(w * h),
    );
    for px in raw.chunks_exact(3) {
        r.push(px[0]);
        g.push(px[1]);
        b.push(px[2]);
    }
    Ok([
        Image::from_vec(w, h, w, r)?,
        Image::from_vec(w, h, w, g)?,
        Image::from_vec(w, h, w, b)?,
    ])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn encode_png_gray8(w: u32, h: u32, data: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        let enc = ::image::codecs::png::PngEncoder::new(&mut out);
        ::image::ImageEncoder::write_image(enc, data, w, h, ::image::ExtendedColorType::L8)
            .unwrap();
        out
    }

    #[test]
    fn stride_access() {
        let img = Image::from_vec(3, 2, 4, vec![1u8, 2, 3, 0, 4, 5, 6, 0]).unwrap();
        assert_eq!(img.get(2, 1), 6);
        assert_eq!(img.row(1), &[4, 5, 6]);
        assert!(Image::from_vec(3, 2, 2, vec![0u8; 8]).is_err());
        assert!(Image::from_vec(3, 2, 4, vec![0u8; 6]).is_err());
        assert_eq!(img.get_checked(-1, 0), None);
        assert_eq!(img.get_checked(3, 0), None);
    }

    #[test]
    fn decode_small_and_corrupt() {
        let one = encode_png_gray8(1, 1, &[77]);
        let g = decode_gray_u8(&one).unwrap();
        assert_eq!((g.width(), g.height(), g.get(0, 0)), (1, 1, 77));
        let odd: Vec<u8> = (0..15).collect();
        let g = decode_gray_u8(&encode_png_gray8(5, 3, &odd)).unwrap();
        assert_eq!(g.get(4, 2), 14);
        let mut corrupt = encode_png_gray8(5, 3, &odd);
        corrupt.truncate(corrupt.len() / 2);
        assert!(decode_gray_u8(&corrupt).is_err());
        assert!(decode_gray_u8(b"not an image at all").is_err());
        assert!(decode_gray_u8(&[]).is_err());
    }

    #[test]
    fn load_missing_file_names_it() {
        let e = load_gray_u8("/nonexistent/dir/x.png").unwrap_err();
        assert!(e.to_string().contains("/nonexistent/dir/x.png"));
        assert!(
            matches!(&e, ImageError::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound),
            "{e}"
        );
        assert!(!e.to_string().contains("decode"), "{e}");
    }

    #[test]
    fn sixteen_bit_png_round_trips() {
        let dir = std::env::temp_dir().join(format!("vision-img-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("d16.png");
        let vals: Vec<u16> = vec![0, 1000, 65535, 257 * 10, 4000, 12];
        let bytes: Vec<u8> = vals.iter().flat_map(|v| v.to_ne_bytes()).collect();
        let mut out = Vec::new();
        let enc = ::image::codecs::png::PngEncoder::new(&mut out);
        ::image::ImageEncoder::write_image(enc, &bytes, 3, 2, ::image::ExtendedColorType::L16)
            .unwrap();
        std::fs::write(&p, &out).unwrap();
        let d = load_u16(&p).unwrap();
        assert_eq!(d.data(), &vals[..]);
        let g = load_gray_u8(&p).unwrap();
        assert_eq!(g.get(2, 0), 255);
        assert_eq!(g.get(0, 1), 10);
        let f = load_gray_f32(&p).unwrap();
        assert!((f.get(1, 0) - 1000.0 / 257.0).abs() < 1e-4);
        std::fs::remove_dir_all(&dir).ok();
    }
}
