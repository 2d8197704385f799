//! A TIFF stack described before any pixel is decoded: which page of which file is each z plane,
//! the checked layout, the spacing and the metadata. Every page's tags are read and checked
//! here (size, type, photometric, compression), so a bad page fails before the volume is
//! allocated.

use super::imagej::ImageJ;
use super::ome::{is_ome_xml, parse_ome_xml, OmePixels};
use super::page::{open_decoder, tiff_err, PageInfo};
use super::TiffOptions;
use crate::volume::formats::read::{format_err, layout, Layout};
use crate::volume::formats::{FileFormat, StoredType, VolumeMeta};
use crate::volume::VolumeError;
use glam::Vec3;
use std::cmp::Ordering;
use std::path::{Path, PathBuf};
use tiff::tags::{ByteOrder, Tag};

/// The file extensions of TIFF files (lowercase, with the dot).
pub(super) const TIFF_EXTENSIONS: [&str; 4] = [".tif", ".tiff", ".btf", ".tf8"];

/// One z plane: page `ifd` of file `file` (an index into [`Stack::files`]).
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub(super) struct Plane {
    /// Index into [`Stack::files`].
    pub file: usize,
    /// The page's IFD index in that file.
    pub ifd: u64,
}

/// What a stack is made of, for reports ([`super::TiffSlabs::info`]).
#[derive(Clone, Debug, PartialEq)]
pub struct TiffInfo {
    /// Files read: one for a multi-page file, every slice for a folder stack.
    pub files: usize,
    /// Pages in the file (all IFDs of its main chain; for a folder stack, the files).
    pub pages: u64,
    /// Pages skipped as reduced-resolution copies (`NewSubfileType` bit 0; plain TIFF only).
    pub reduced_skipped: u64,
    /// The first plane's `Compression` code.
    pub compression: u16,
    /// True when the first plane is tiled.
    pub tiled: bool,
    /// The OME-XML `Pixels` of the image read, for an OME-TIFF.
    pub ome: Option<OmePixels>,
    /// The ImageJ hyperstack description, for an ImageJ / Fiji TIFF (without OME-XML).
    pub imagej: Option<ImageJ>,
    /// The channel and time point read (0 for a plain stack).
    pub channel_time: [u64; 2],
}

/// A checked stack.
#[derive(Clone, Debug)]
pub(super) struct Stack {
    /// The path given (a file or a folder), named in errors about the whole stack.
    pub path: PathBuf,
    /// The files holding the planes.
    pub files: Vec<PathBuf>,
    /// Plane z is `planes[z]`.
    pub planes: Vec<Plane>,
    /// Dims, voxel count and stored type.
    pub layout: Layout,
    /// Voxel spacing (µm for an OME-TIFF with physical sizes, else 1).
    pub spacing: Vec3,
    /// What the file says besides the voxels.
    pub meta: VolumeMeta,
    /// For reports.
    pub info: TiffInfo,
}

/// What the first page says besides its pixels.
struct FirstPage {
    /// `ImageDescription`.
    description: Option<String>,
    /// `XResolution`, `YResolution` (pixels per unit), where present.
    resolution: [Option<f64>; 2],
    /// The file is big-endian.
    big_endian: bool,
}

/// Reads the tags of every page of `path` (the main IFD chain, in order) and the first page's
/// `ImageDescription` and resolution.
fn read_pages(path: &Path) -> Result<(Vec<PageInfo>, FirstPage), VolumeError> {
    let mut dec = open_decoder(path)?;
    let big_endian = dec.byte_order() == ByteOrder::BigEndian;
    let description = match dec.find_tag(Tag::ImageDescription) {
        Ok(Some(v)) => v.into_string().ok(),
        Ok(None) => None,
        Err(e) => return Err(tiff_err(path, 0, "ImageDescription", e)),
    };
    let mut resolution = [None; 2];
    for (slot, (tag, field)) in resolution.iter_mut().zip([
        (Tag::XResolution, "XResolution"),
        (Tag::YResolution, "YResolution"),
    ]) {
        *slot = match dec.find_tag(tag) {
            Ok(Some(v)) => rational(v).filter(|r| r.is_finite() && *r > 0.0),
            Ok(None) => None,
            Err(e) => return Err(tiff_err(path, 0, field, e)),
        };
    }
    let mut pages = vec![PageInfo::read(&mut dec, path, 0)?];
    while dec.more_images() {
        let page = pages.len() as u64;
        dec.next_image()
            .map_err(|e| tiff_err(path, page, "IFD", e))?;
        pages.push(PageInfo::read(&mut dec, path, page)?);
    }
    let first = FirstPage {
        description,
        resolution,
        big_endian,
    };
    Ok((pages, first))
}

/// A RATIONAL (or float) tag value as a number.
fn rational(v: tiff::decoder::ifd::Value) -> Option<f64> {
    use tiff::decoder::ifd::Value;
    match v {
        Value::Rational(n, d) if d != 0 => Some(f64::from(n) / f64::from(d)),
        Value::Float(f) => Some(f64::from(f)),
        Value::Double(f) => Some(f),
        _ => None,
    }
}

/// Describes the stack at `path`: a multi-page TIFF (plain or OME-TIFF), or a folder of
/// single-page TIFFs.
pub(super) fn describe(path: &Path, options: &TiffOptions) -> Result<Stack, VolumeError> {
    if path.is_dir() {
        return describe_folder(path, options);
    }
    let (pages, first_page) = read_pages(path)?;
    let big_endian = first_page.big_endian;
    let ome = match first_page.description.as_deref() {
        Some(d) if is_ome_xml(d) => Some(parse_ome_xml(path, d.as_bytes())?),
        _ => None,
    };
    let imagej = match (&ome, first_page.description.as_deref()) {
        (None, Some(d)) => ImageJ::parse(d),
        _ => None,
    };
    let mut reduced_skipped = 0;
    let (planes, pixels) = match ome {
        Some(ome) => {
            let count = ome.images.len();
            let Some(pixels) = ome.images.into_iter().nth(options.image) else {
                return Err(format_err(
                    path,
                    "Image",
                    format!(
                        "image {} asked for; the OME-XML holds {count} (0..{count})",
                        options.image
                    ),
                ));
            };
            (
                ome_planes(path, &pixels, options, pages.len() as u64)?,
                Some(pixels),
            )
        }
        None if imagej.is_some() => {
            let ij = imagej.as_ref().expect("matched");
            (imagej_planes(path, ij, options, pages.len() as u64)?, None)
        }
        None => {
            check_plain_options(path, options)?;
            let planes: Vec<Plane> = (0..pages.len() as u64)
                .filter(|&i| !pages[i as usize].is_reduced())
                .map(|ifd| Plane { file: 0, ifd })
                .collect();
            reduced_skipped = pages.len() as u64 - planes.len() as u64;
            (planes, None)
        }
    };
    let infos: Vec<(&PageInfo, &Path, u64)> = planes
        .iter()
        .map(|p| (&pages[p.ifd as usize], path, p.ifd))
        .collect();
    let (first, stored) = check_planes(path, &infos)?;
    let mut spacing = Vec3::ONE;
    if let Some(px) = &pixels {
        check_ome_against_pages(path, px, first, stored)?;
        for (axis, um) in px.physical_um.iter().enumerate() {
            if let Some(um) = um {
                spacing[axis] = *um as f32;
            }
        }
    }
    if let Some(ij) = &imagej {
        let to_um = ij.micrometres_per_unit().unwrap_or(1.0);
        let [x, y] = first_page.resolution.map(|r| r.map(|r| 1.0 / r));
        for (axis, size) in [x, y, ij.spacing].into_iter().enumerate() {
            let value = (size.unwrap_or(1.0) * to_um) as f32;
            if value.is_normal() && value > 0.0 {
                spacing[axis] = value;
            }
        }
    }
    let layout = layout(
        path,
        "ImageWidth",
        [
            u64::from(first.width),
            u64::from(first.height),
            planes.len() as u64,
        ],
        stored,
    )?;
    let info = TiffInfo {
        files: 1,
        pages: pages.len() as u64,
        reduced_skipped,
        compression: first.compression,
        tiled: first.tiled,
        ome: pixels,
        imagej,
        channel_time: [options.channel, options.time],
    };
    Ok(Stack {
        path: path.to_path_buf(),
        files: vec![path.to_path_buf()],
        planes,
        layout,
        spacing,
        meta: VolumeMeta::plain(FileFormat::Tiff, stored, big_endian),
        info,
    })
}

/// Channel and time selections need an OME-TIFF.
fn check_plain_options(path: &Path, options: &TiffOptions) -> Result<(), VolumeError> {
    for (value, field) in [
        (options.channel, "SizeC"),
        (options.time, "SizeT"),
        (options.image as u64, "Image"),
    ] {
        if value != 0 {
            return Err(format_err(
                path,
                field,
                format!(
                    "{field} selection {value} asked for, but this is neither an OME-TIFF nor \
                     an ImageJ hyperstack (no OME-XML or ImageJ= ImageDescription): its pages \
                     are the z planes"
                ),
            ));
        }
    }
    Ok(())
}

/// The pages holding planes (z, `options.channel`, `options.time`) for z in `0..SizeZ`.
fn ome_planes(
    path: &Path,
    px: &OmePixels,
    options: &TiffOptions,
    pages: u64,
) -> Result<Vec<Plane>, VolumeError> {
    let [_, _, size_z, size_c, size_t] = px.size;
    for (value, size, field, what) in [
        (options.channel, size_c, "SizeC", "channel"),
        (options.time, size_t, "SizeT", "time point"),
    ] {
        if value >= size {
            return Err(format_err(
                path,
                field,
                format!("{what} {value} asked for; the image has {field} = {size} (0..{size})"),
            ));
        }
    }
    // Bounded before anything is allocated: each plane is a distinct page.
    if size_z > pages {
        return Err(format_err(
            path,
            "SizeZ",
            format!("SizeZ = {size_z} but the file holds only {pages} pages"),
        ));
    }
    let mut planes = Vec::with_capacity(size_z as usize);
    for z in 0..size_z {
        let zct = [z, options.channel, options.time];
        let ifd = px.ifd_of(path, zct)?.ok_or_else(|| {
            format_err(
                path,
                "TiffData",
                format!(
                    "no TiffData element holds plane (z={z}, c={}, t={})",
                    options.channel, options.time
                ),
            )
        })?;
        if ifd >= pages {
            return Err(format_err(
                path,
                "TiffData",
                format!(
                    "plane (z={z}, c={}, t={}) is in IFD {ifd} ({}), but the file holds {pages} \
                     pages",
                    options.channel,
                    options.time,
                    px.dimension_order.name()
                ),
            ));
        }
        planes.push(Plane { file: 0, ifd });
    }
    Ok(planes)
}

/// The pages holding planes (z, `options.channel`, `options.time`) of an ImageJ hyperstack
/// (CZT order: channel fastest).
fn imagej_planes(
    path: &Path,
    ij: &ImageJ,
    options: &TiffOptions,
    pages: u64,
) -> Result<Vec<Plane>, VolumeError> {
    for (value, size, field, what) in [
        (options.image as u64, 1, "Image", "image"),
        (options.channel, ij.channels, "channels", "channel"),
        (options.time, ij.frames, "frames", "time point (frame)"),
    ] {
        if value >= size {
            return Err(format_err(
                path,
                field,
                format!(
                    "{what} {value} asked for; the ImageJ hyperstack has {field}={size} (0..{size})"
                ),
            ));
        }
    }
    if ij.slices > pages {
        return Err(format_err(
            path,
            "slices",
            format!("slices={} but the file holds only {pages} pages", ij.slices),
        ));
    }
    (0..ij.slices)
        .map(|z| match ij.page_of(z, options.channel, options.time) {
            Some(ifd) if ifd < pages => Ok(Plane { file: 0, ifd }),
            _ => Err(format_err(
                path,
                "images",
                format!(
                    "plane (z={z}, c={}, t={}) of {}x{}x{} (channels x slices x frames) is past \
                     the file's {pages} pages",
                    options.channel, options.time, ij.channels, ij.slices, ij.frames
                ),
            )),
        })
        .collect()
}

/// Checks the OME `Pixels` against the first plane's page: `SizeX` / `SizeY` and `Type`.
fn check_ome_against_pages(
    path: &Path,
    px: &OmePixels,
    first: &PageInfo,
    stored: StoredType,
) -> Result<(), VolumeError> {
    for (field, ome, page) in [
        ("SizeX", px.size[0], first.width),
        ("SizeY", px.size[1], first.height),
    ] {
        if ome != u64::from(page) {
            return Err(format_err(
                path,
                field,
                format!("OME-XML {field} = {ome} but the pages are {page} pixels"),
            ));
        }
    }
    match px.stored {
        Some(t) if t == stored => Ok(()),
        _ => Err(format_err(
            path,
            "Type",
            format!(
                "OME-XML Type = {:?} but the pages hold {}",
                px.type_name,
                stored.name()
            ),
        )),
    }
}

/// Checks every plane's page (`(info, file, page)`) against the first; returns the first and
/// its stored type.
fn check_planes<'a>(
    path: &Path,
    planes: &[(&'a PageInfo, &Path, u64)],
) -> Result<(&'a PageInfo, StoredType), VolumeError> {
    let Some(&(first, first_path, first_page)) = planes.first() else {
        return Err(format_err(
            path,
            "IFD",
            "no full-resolution page to stack (every page is a reduced-resolution copy)",
        ));
    };
    let first_stored = first.stored_type(first_path, first_page)?;
    let first_at = (first_path.to_path_buf(), first_page);
    for &(info, file, page) in &planes[1..] {
        let stored = info.stored_type(file, page)?;
        info.check_matches(stored, file, page, first, first_stored, &first_at)?;
    }
    Ok((first, first_stored))
}

/// A folder of single-page TIFFs, in natural name order (`slice2` before `slice10`).
fn describe_folder(dir: &Path, options: &TiffOptions) -> Result<Stack, VolumeError> {
    check_plain_options(dir, options)?;
    let files = tiff_files_in(dir)?;
    if files.is_empty() {
        return Err(format_err(
            dir,
            "extension",
            "the folder holds no .tif / .tiff files to stack",
        ));
    }
    let mut infos = Vec::with_capacity(files.len());
    let mut big_endian = false;
    for (i, file) in files.iter().enumerate() {
        let mut dec = open_decoder(file)?;
        if i == 0 {
            big_endian = dec.byte_order() == ByteOrder::BigEndian;
        }
        if dec.more_images() {
            return Err(VolumeError::TiffPage {
                path: file.clone(),
                page: i as u64,
                field: "IFD".into(),
                message: "the file holds more than one page; a folder stack takes single-page \
                          TIFFs (give a multi-page file by its own name)"
                    .into(),
            });
        }
        infos.push(PageInfo::read(&mut dec, file, i as u64)?);
    }
    let planes: Vec<(&PageInfo, &Path, u64)> = infos
        .iter()
        .zip(&files)
        .enumerate()
        .map(|(i, (info, file))| (info, file.as_path(), i as u64))
        .collect();
    let (first, stored) = check_planes(dir, &planes)?;
    let layout = layout(
        dir,
        "ImageWidth",
        [
            u64::from(first.width),
            u64::from(first.height),
            files.len() as u64,
        ],
        stored,
    )?;
    let info = TiffInfo {
        files: files.len(),
        pages: files.len() as u64,
        reduced_skipped: 0,
        compression: first.compression,
        tiled: first.tiled,
        ome: None,
        imagej: None,
        channel_time: [0, 0],
    };
    Ok(Stack {
        path: dir.to_path_buf(),
        planes: (0..files.len())
            .map(|file| Plane { file, ifd: 0 })
            .collect(),
        files,
        layout,
        spacing: Vec3::ONE,
        meta: VolumeMeta::plain(FileFormat::Tiff, stored, big_endian),
        info,
    })
}

/// True when `name` ends with a TIFF extension (case-insensitive).
pub(in crate::volume::formats) fn has_tiff_extension(name: &str) -> bool {
    let lower = name.to_ascii_lowercase();
    TIFF_EXTENSIONS
        .iter()
        .any(|ext| lower.len() > ext.len() && lower.ends_with(ext))
}

/// The TIFF files directly in `dir`, in natural name order.
pub(super) fn tiff_files_in(dir: &Path) -> Result<Vec<PathBuf>, VolumeError> {
    let entries = std::fs::read_dir(dir).map_err(|source| VolumeError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut files = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|source| VolumeError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
        let name = entry.file_name().to_string_lossy().into_owned();
        if !name.starts_with('.') && has_tiff_extension(&name) && entry.path().is_file() {
            files.push(entry.path());
        }
    }
    files.sort_by(|a, b| natural_cmp(&a.to_string_lossy(), &b.to_string_lossy()));
    Ok(files)
}

/// Compares names with runs of digits compared as numbers (`z9` < `z10`).
fn natural_cmp(a: &str, b: &str) -> Ordering {
    let (mut a, mut b) = (a.as_bytes(), b.as_bytes());
    loop {
        match (a.first(), b.first()) {
            (None, None) => return Ordering::Equal,
            (None, Some(_)) => return Ordering::Less,
            (Some(_), None) => return Ordering::Greater,
            (Some(x), Some(y)) if x.is_ascii_digit() && y.is_ascii_digit() => {
                let da = a.iter().take_while(|c| c.is_ascii_digit()).count();
                let db = b.iter().take_while(|c| c.is_ascii_digit()).count();
                let (na, nb) = (&a[..da], &b[..db]);
                let trim = |n: &[u8]| {
                    let zeros = n.iter().take_while(|&&c| c == b'0').count();
                    n.len() - zeros
                };
                let (ta, tb) = (trim(na), trim(nb));
                let ord = ta
                    .cmp(&tb)
                    .then_with(|| na[da - ta..].cmp(&nb[db - tb..]))
                    .then_with(|| da.cmp(&db));
                if ord != Ordering::Equal {
                    return ord;
                }
                a = &a[da..];
                b = &b[db..];
            }
            (Some(x), Some(y)) => {
                if x != y {
                    return x.cmp(y);
                }
                a = &a[1..];
                b = &b[1..];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_sort_naturally() {
        let mut names = vec!["z10.tif", "z9.tif", "z0010.tif", "a.tif", "z1.tif"];
        names.sort_by(|a, b| natural_cmp(a, b));
        assert_eq!(names, ["a.tif", "z1.tif", "z9.tif", "z10.tif", "z0010.tif"]);
    }
}
