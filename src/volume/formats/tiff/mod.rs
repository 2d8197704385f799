//! TIFF stacks as volumes, through image-rs' `tiff` crate: multi-page grey TIFF and BigTIFF
//! (`.tif`, `.tiff`, `.btf`, `.tf8`), OME-TIFF (`.ome.tif`), and folders of single-page TIFFs.
//!
//! # What is read
//!
//! - **Pages**: each z plane is one page (IFD) holding one grey sample per pixel
//!   (`SamplesPerPixel` 1, `PhotometricInterpretation` BlackIsZero), stripped or tiled, in
//!   classic TIFF or BigTIFF, either byte order, uncompressed or LZW, Deflate (8 and 32946),
//!   PackBits or Zstd, with or without a horizontal or floating-point predictor. Types follow
//!   [the value table](super#value-mapping): u8, u16 as is; i8, i16 with their offsets; f32 as
//!   is (NaN / infinity refused); u32, i32 converted to f32 (exact up to 2^24) and f64 rounded
//!   to f32 (values beyond f32 refused as non-finite). RGB, palette, WhiteIsZero, multi-sample
//!   pages, 1 / 12-bit samples, f16, complex and JPEG / fax pages are refused with a
//!   [`VolumeError::TiffPage`] naming the page and the tag.
//! - **Plain TIFF**: the pages of the main IFD chain, in order, are the z planes; pages marked
//!   as reduced-resolution copies (`NewSubfileType` bit 0: thumbnails, pyramid levels) are
//!   skipped. Spacing is 1 (TIFF resolution tags are print resolutions).
//! - **OME-TIFF** (OME-XML in the first page's `ImageDescription`, see [`parse_ome_xml`]):
//!   image `TiffOptions::image` (default 0) of the document; its `SizeX` / `SizeY` / `Type`
//!   must agree with the pages; the z planes are (z, c, t) for z in `0..SizeZ` at channel
//!   [`TiffOptions::channel`] and time [`TiffOptions::time`] (default 0 and 0), located through
//!   `DimensionOrder` and the `TiffData` elements (`IFD`, `FirstZ/C/T`, `PlaneCount`). A
//!   channel or time beyond `SizeC` / `SizeT` is a [`VolumeError::Format`] error on that
//!   field; planes in another file (multi-file OME-TIFF, `TiffData/UUID`) are refused on
//!   `TiffData`. Spacing is `PhysicalSizeX/Y/Z` in micrometres (converted from their units);
//!   an absent physical size counts as 1 µm.
//! - **ImageJ / Fiji hyperstacks** (an `ImageJ=` description, without OME-XML; see
//!   [`ImageJ`]): the z planes are `slices` at [`TiffOptions::channel`] and
//!   [`TiffOptions::time`] (the `channels` and `frames`, CZT page order); spacing is
//!   1 / `XResolution`, 1 / `YResolution` and `spacing`, in micrometres when `unit` is a known
//!   length (`micron`, `nm`, `mm`, ...), else in the file's unit.
//! - **Folder stacks**: a folder of single-page `.tif` / `.tiff` files, in natural name order
//!   (`slice9` before `slice10`); every file must hold one page.
//!
//! # Safety and memory
//!
//! Every page's tags are read and checked when the stack is opened, before a voxel buffer
//! exists: every plane must have the first plane's size and type (else a
//! [`VolumeError::TiffPage`] naming the page, on `ImageWidth` / `ImageLength` /
//! `SampleFormat`), and the volume passes the checked layout of [`super`] (axes, 16 GiB) and
//! the host-memory check. Tag values are capped at 64 MiB; a file that ends inside a page's
//! data is a [`VolumeError::TiffPage`] on `data`. [`TiffSlabs`] reads z planes one page at a
//! time, decoding straight into the caller's slab, so `mixvol convert stack.tif store` streams
//! the pages in bounded RAM.

mod imagej;
mod ome;
mod page;
mod slabs;
mod stack;

pub use imagej::ImageJ;
pub use ome::{is_ome_xml, parse_ome_xml, DimensionOrder, OmePixels, OmeXml, TiffData};
pub use slabs::TiffSlabs;
pub(in crate::volume::formats) use stack::has_tiff_extension;
pub use stack::TiffInfo;

use super::LoadedVolume;
use crate::volume::VolumeError;
use std::path::Path;

/// Which image, channel and time point of an OME-TIFF (or channel and frame of an ImageJ
/// hyperstack) to read (all 0 by default; plain TIFF stacks accept only 0).
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Hash)]
pub struct TiffOptions {
    /// The OME `Image` (series) index.
    pub image: usize,
    /// The channel (`0..SizeC`).
    pub channel: u64,
    /// The time point (`0..SizeT`).
    pub time: u64,
}

/// Loads a TIFF stack (a multi-page TIFF, an OME-TIFF at channel 0 / time 0, or a folder of
/// single-page TIFFs); see the [module docs](self).
pub fn load_tiff(path: &Path) -> Result<LoadedVolume, VolumeError> {
    load_tiff_with(path, &TiffOptions::default())
}

/// [`load_tiff`] with an OME image, channel and time point.
pub fn load_tiff_with(path: &Path, options: &TiffOptions) -> Result<LoadedVolume, VolumeError> {
    TiffSlabs::open(path, options)?.load()
}

/// True when `path` is a folder holding at least one TIFF file (a folder stack).
pub fn is_tiff_folder(path: &Path) -> bool {
    path.is_dir() && stack::tiff_files_in(path).is_ok_and(|f| !f.is_empty())
}
