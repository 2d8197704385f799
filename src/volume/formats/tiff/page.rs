//! One TIFF page (IFD): what its tags say, read through the `tiff` crate's decoder, and the
//! checks that make it a grey plane of a volume.

use super::super::StoredType;
use crate::volume::VolumeError;
use std::fs::File;
use std::io::{BufReader, ErrorKind};
use std::path::{Path, PathBuf};
use tiff::decoder::{ChunkType, Decoder, Limits};
use tiff::tags::{CompressionMethod, Tag};
use tiff::TiffError;

/// The decoder over one TIFF file.
pub(super) type TiffDecoder = Decoder<BufReader<File>>;

/// The largest value of one tag the decoder reads (an OME-XML description, a page's strip
/// offsets): 64 MiB.
const MAX_TAG_BYTES: usize = 64 << 20;

/// Opens `path` with the decoder, on its first page (page 0). The decoder's own buffer limit is
/// the volume limit: a page is decoded into the caller's slab, whose size is checked before.
pub(super) fn open_decoder(path: &Path) -> Result<TiffDecoder, VolumeError> {
    let (file, _) = super::super::read::open_regular(path)?;
    let mut limits = Limits::default();
    limits.decoding_buffer_size = super::super::MAX_VOLUME_BYTES as usize;
    limits.ifd_value_size = MAX_TAG_BYTES;
    Decoder::new(BufReader::new(file))
        .map(|d| d.with_limits(limits))
        .map_err(|e| tiff_err(path, 0, "header", e))
}

/// Maps a decoder error on page `page` of `path` to a typed error: a file that ends inside the
/// page is reported as truncated, other IO errors are [`VolumeError::Io`].
pub(super) fn tiff_err(path: &Path, page: u64, field: &str, e: TiffError) -> VolumeError {
    let page_err = |field: &str, message: String| VolumeError::TiffPage {
        path: path.to_path_buf(),
        page,
        field: field.into(),
        message,
    };
    match e {
        TiffError::IoError(io) if io.kind() == ErrorKind::UnexpectedEof => page_err(
            field,
            format!("the file ends inside this page's {field} (truncated?): {io}"),
        ),
        TiffError::IoError(io) => VolumeError::Io {
            path: path.to_path_buf(),
            source: io,
        },
        TiffError::LimitsExceeded => page_err(
            field,
            format!(
                "a tag value or buffer exceeds the decoder limits ({} MiB per tag, {} GiB per page)",
                MAX_TAG_BYTES >> 20,
                super::super::MAX_VOLUME_BYTES >> 30
            ),
        ),
        other => page_err(field, other.to_string()),
    }
}

/// What one page's tags say (read before any pixel is decoded).
#[derive(Clone, Debug, PartialEq, Eq)]
pub(super) struct PageInfo {
    /// `ImageWidth`, `ImageLength`.
    pub width: u32,
    /// `ImageLength`.
    pub height: u32,
    /// `SamplesPerPixel`.
    pub samples: u16,
    /// `PhotometricInterpretation`.
    pub photometric: u16,
    /// `BitsPerSample` (the same for every sample: the decoder refuses mixed sizes).
    pub bits: u8,
    /// `SampleFormat`: 1 unsigned, 2 signed, 3 float.
    pub sample_format: u16,
    /// `Compression`.
    pub compression: u16,
    /// True for tiled pages (`TileWidth`), false for strips.
    pub tiled: bool,
    /// `NewSubfileType` (bit 0: a reduced-resolution copy, e.g. a thumbnail or a pyramid level).
    pub subfile: u32,
}

impl PageInfo {
    /// Reads the tags of the decoder's current page (`page` of `path`, for errors).
    pub fn read(dec: &mut TiffDecoder, path: &Path, page: u64) -> Result<Self, VolumeError> {
        let err = |field: &'static str| move |e| tiff_err(path, page, field, e);
        let (width, height) = dec.dimensions().map_err(err("ImageWidth"))?;
        let samples = dec
            .find_tag_unsigned::<u16>(Tag::SamplesPerPixel)
            .map_err(err("SamplesPerPixel"))?
            .unwrap_or(1);
        let photometric = dec
            .find_tag_unsigned::<u16>(Tag::PhotometricInterpretation)
            .map_err(err("PhotometricInterpretation"))?
            .unwrap_or(1);
        let bits = dec
            .find_tag_unsigned_vec::<u16>(Tag::BitsPerSample)
            .map_err(err("BitsPerSample"))?
            .and_then(|v| v.first().copied())
            .unwrap_or(1);
        let sample_format = dec
            .find_tag_unsigned_vec::<u16>(Tag::SampleFormat)
            .map_err(err("SampleFormat"))?
            .and_then(|v| v.first().copied())
            .unwrap_or(1);
        let compression = dec
            .find_tag_unsigned::<u16>(Tag::Compression)
            .map_err(err("Compression"))?
            .unwrap_or(1);
        let subfile = dec
            .find_tag_unsigned::<u32>(Tag::NewSubfileType)
            .map_err(err("NewSubfileType"))?
            .unwrap_or(0);
        Ok(Self {
            width,
            height,
            samples,
            photometric,
            bits: u8::try_from(bits).unwrap_or(u8::MAX),
            sample_format,
            compression,
            tiled: dec.get_chunk_type() == ChunkType::Tile,
            subfile,
        })
    }

    /// True for a reduced-resolution copy of another page (`NewSubfileType` bit 0).
    pub fn is_reduced(&self) -> bool {
        self.subfile & 1 != 0
    }

    /// Checks that the page is one grey plane mixvol decodes and returns its stored type:
    /// `SamplesPerPixel` 1, `PhotometricInterpretation` BlackIsZero, unsigned / signed 8, 16
    /// or 32-bit integers or 32 / 64-bit floats, and a compression the decoder was built with.
    pub fn stored_type(&self, path: &Path, page: u64) -> Result<StoredType, VolumeError> {
        let refuse = |field: &str, message: String| VolumeError::TiffPage {
            path: path.to_path_buf(),
            page,
            field: field.into(),
            message,
        };
        if self.photometric != 1 {
            let name = match self.photometric {
                0 => "WhiteIsZero (inverted grey)",
                2 => "RGB",
                3 => "Palette",
                4 => "TransparencyMask",
                5 => "CMYK",
                6 => "YCbCr",
                8..=10 => "CIELab",
                _ => "unknown",
            };
            return Err(refuse(
                "PhotometricInterpretation",
                format!(
                    "{} = {name}; a volume's pages must be BlackIsZero grey (1)",
                    self.photometric
                ),
            ));
        }
        if self.samples != 1 {
            return Err(refuse(
                "SamplesPerPixel",
                format!(
                    "{} samples per pixel; a volume's pages hold one grey sample (store channels \
                     as pages, e.g. an OME-TIFF with SizeC)",
                    self.samples
                ),
            ));
        }
        let stored = match (self.sample_format, self.bits) {
            (1, 8) => StoredType::U8,
            (2, 8) => StoredType::I8,
            (1, 16) => StoredType::U16,
            (2, 16) => StoredType::I16,
            (1, 32) => StoredType::U32,
            (2, 32) => StoredType::I32,
            (3, 32) => StoredType::F32,
            (3, 64) => StoredType::F64,
            (1..=3, bits) if ![8, 16, 32, 64].contains(&bits) => {
                return Err(refuse(
                    "BitsPerSample",
                    format!("{bits} bits per sample; supported: 8, 16, 32 (and 64-bit floats)"),
                ))
            }
            (format, bits) => {
                let kind = match format {
                    1 => "unsigned integer",
                    2 => "signed integer",
                    3 => "float",
                    4 => "undefined",
                    5 => "complex integer",
                    6 => "complex float",
                    _ => "unknown",
                };
                return Err(refuse(
                    "SampleFormat",
                    format!(
                        "{format} ({kind}) with {bits} bits; supported: u8, i8, u16, i16, u32, \
                         i32, f32, f64"
                    ),
                ));
            }
        };
        let method = CompressionMethod::from_u16_exhaustive(self.compression);
        let known = matches!(
            method,
            CompressionMethod::None
                | CompressionMethod::LZW
                | CompressionMethod::Deflate
                | CompressionMethod::OldDeflate
                | CompressionMethod::PackBits
                | CompressionMethod::ZSTD
        );
        if !known {
            return Err(refuse(
                "Compression",
                format!(
                    "{} ({method:?}) is not decoded; supported: none (1), LZW (5), Deflate (8, \
                     32946), PackBits (32773), Zstd (50000)",
                    self.compression
                ),
            ));
        }
        Ok(stored)
    }

    /// Checks that this page (`page` of `path`) has the size and type of the stack's first page
    /// `first` (`first_page` of `first_path`).
    pub fn check_matches(
        &self,
        stored: StoredType,
        path: &Path,
        page: u64,
        first: &PageInfo,
        first_stored: StoredType,
        first_at: &(PathBuf, u64),
    ) -> Result<(), VolumeError> {
        let of_first = || {
            if first_at.0 == path {
                format!("page {}", first_at.1)
            } else {
                format!("page {} of {}", first_at.1, first_at.0.display())
            }
        };
        let refuse = |field: &str, message: String| VolumeError::TiffPage {
            path: path.to_path_buf(),
            page,
            field: field.into(),
            message,
        };
        if (self.width, self.height) != (first.width, first.height) {
            let field = if self.width != first.width {
                "ImageWidth"
            } else {
                "ImageLength"
            };
            return Err(refuse(
                field,
                format!(
                    "the page is {}x{} but {} is {}x{}; every page of a stack must have one size",
                    self.width,
                    self.height,
                    of_first(),
                    first.width,
                    first.height
                ),
            ));
        }
        if stored != first_stored {
            return Err(refuse(
                "SampleFormat",
                format!(
                    "the page holds {} but {} holds {}; every page of a stack must have one type",
                    stored.name(),
                    of_first(),
                    first_stored.name()
                ),
            ));
        }
        Ok(())
    }
}
