//! OME-XML, the metadata an OME-TIFF keeps in its first page's `ImageDescription`: image sizes,
//! dimension order, pixel type, physical sizes and which TIFF page (IFD) holds each plane.
//!
//! Parsed with `roxmltree` (a read-only DOM; DTDs, hence entity expansion, refused; a node limit
//! bounds the tree). Elements are matched by local name, so every OME schema namespace
//! (2008-02 ... 2016-06) reads the same. Only what a volume needs is read: the `Pixels` of each
//! `Image` and their `TiffData`; everything else (channels' colours, instruments, annotations)
//! is ignored.

use super::super::read::format_err;
use super::super::StoredType;
use crate::volume::VolumeError;
use std::path::Path;

/// The largest number of XML nodes parsed (elements, attributes' text, ...): an OME-XML of a
/// few thousand planes holds far fewer.
const MAX_XML_NODES: u32 = 1 << 20;

/// The order of the Z, C and T planes in the pages of an OME-TIFF (`Pixels/@DimensionOrder`),
/// fastest first after X and Y: `XYZCT` stores all Z planes of channel 0 at time 0, then those
/// of channel 1, ...
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub struct DimensionOrder {
    /// The three axes after X and Y, fastest first: 0 = Z, 1 = C, 2 = T.
    axes: [usize; 3],
}

impl DimensionOrder {
    /// Parses `XYZCT`, `XYZTC`, `XYCZT`, `XYCTZ`, `XYTZC` or `XYTCZ`.
    pub fn parse(text: &str) -> Option<Self> {
        let rest = text.strip_prefix("XY")?;
        let mut axes = [0usize; 3];
        let mut seen = [false; 3];
        if rest.len() != 3 {
            return None;
        }
        for (slot, ch) in axes.iter_mut().zip(rest.chars()) {
            let axis = match ch {
                'Z' => 0,
                'C' => 1,
                'T' => 2,
                _ => return None,
            };
            if std::mem::replace(&mut seen[axis], true) {
                return None;
            }
            *slot = axis;
        }
        Some(Self { axes })
    }

    /// The order as OME writes it, e.g. `XYZCT`.
    pub fn name(self) -> String {
        let mut s = String::from("XY");
        s.extend(self.axes.iter().map(|&a| ['Z', 'C', 'T'][a]));
        s
    }

    /// The plane index of (z, c, t) among `sizes` = (SizeZ, SizeC, SizeT) planes; `None` when
    /// it overflows.
    pub fn plane_index(self, zct: [u64; 3], sizes: [u64; 3]) -> Option<u64> {
        let [a, b, c] = self.axes;
        zct[c]
            .checked_mul(sizes[b])?
            .checked_add(zct[b])?
            .checked_mul(sizes[a])?
            .checked_add(zct[a])
    }
}

/// One `TiffData` element: `plane_count` planes, in the dimension order from plane
/// (`first_z`, `first_c`, `first_t`), are in consecutive IFDs from `ifd`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TiffData {
    /// The first IFD (page index in the file's main IFD chain), `IFD` (default 0).
    pub ifd: u64,
    /// `FirstZ`, `FirstC`, `FirstT` (default 0).
    pub first: [u64; 3],
    /// `PlaneCount`; `None` when absent (then 1 if `IFD` is given, else every plane).
    pub plane_count: Option<u64>,
    /// True when `IFD` was given.
    pub ifd_given: bool,
    /// `UUID/@FileName`, when the planes live in another file (multi-file OME-TIFF).
    pub file_name: Option<String>,
}

/// The `Pixels` of one OME `Image`.
#[derive(Clone, Debug, PartialEq)]
pub struct OmePixels {
    /// `SizeX`, `SizeY`, `SizeZ`, `SizeC`, `SizeT`.
    pub size: [u64; 5],
    /// `DimensionOrder`.
    pub dimension_order: DimensionOrder,
    /// `Type` mapped to a stored type (`None` for types a volume cannot hold: `bit`,
    /// `complex`, `double-complex`).
    pub stored: Option<StoredType>,
    /// `Type` as written.
    pub type_name: String,
    /// `PhysicalSizeX`, `PhysicalSizeY`, `PhysicalSizeZ` in micrometres (converted from their
    /// `PhysicalSize*Unit`, default µm); `None` where absent.
    pub physical_um: [Option<f64>; 3],
    /// The `TiffData` elements, in document order (empty: planes are IFDs 0, 1, ... in the
    /// dimension order).
    pub tiff_data: Vec<TiffData>,
}

impl OmePixels {
    /// The IFD holding plane (z, c, t), from the `TiffData` elements; `Ok(None)` when none
    /// covers it. A plane in another file is a [`VolumeError::Format`] error on `TiffData`.
    pub fn ifd_of(&self, path: &Path, zct: [u64; 3]) -> Result<Option<u64>, VolumeError> {
        let sizes = [self.size[2], self.size[3], self.size[4]];
        let order = self.dimension_order;
        let index = order
            .plane_index(zct, sizes)
            .ok_or_else(|| format_err(path, "SizeZ", "plane index overflows (sizes too large)"))?;
        if self.tiff_data.is_empty() {
            return Ok(Some(index));
        }
        // Later elements override earlier ones, as in Bio-Formats.
        let mut found = None;
        for d in &self.tiff_data {
            let start = order
                .plane_index(d.first, sizes)
                .ok_or_else(|| format_err(path, "TiffData", "FirstZ / FirstC / FirstT overflow"))?;
            let count = d
                .plane_count
                .unwrap_or(if d.ifd_given { 1 } else { u64::MAX });
            if index >= start && index - start < count {
                if let Some(name) = &d.file_name {
                    let own = path.file_name().map(|n| n.to_string_lossy().into_owned());
                    if own.as_deref() != Some(name.as_str()) {
                        return Err(format_err(
                            path,
                            "TiffData",
                            format!(
                                "plane (z={}, c={}, t={}) is in another file, {name}: \
                                 multi-file OME-TIFF is not supported",
                                zct[0], zct[1], zct[2]
                            ),
                        ));
                    }
                }
                found =
                    Some(d.ifd.checked_add(index - start).ok_or_else(|| {
                        format_err(path, "TiffData", "IFD + plane offset overflows")
                    })?);
            }
        }
        Ok(found)
    }
}

/// What an OME-XML document says about its images.
#[derive(Clone, Debug, PartialEq)]
pub struct OmeXml {
    /// The `Pixels` of every `Image`, in document order.
    pub images: Vec<OmePixels>,
}

/// True when an `ImageDescription` looks like OME-XML (an XML document with an `OME` element).
pub fn is_ome_xml(description: &str) -> bool {
    let t = description.trim_start();
    t.starts_with('<') && (t.contains("<OME") || t.contains(":OME"))
}

/// Parses an OME-XML document (bytes, as in the TIFF tag; UTF-8). Errors are
/// [`VolumeError::Format`] errors naming `path` and the OME attribute at fault (`SizeZ`,
/// `DimensionOrder`, `PhysicalSizeXUnit`, `TiffData`, ...; `OME-XML` for the document itself).
pub fn parse_ome_xml(path: &Path, bytes: &[u8]) -> Result<OmeXml, VolumeError> {
    let text = std::str::from_utf8(bytes)
        .map_err(|e| format_err(path, "OME-XML", format!("not UTF-8: {e}")))?;
    let options = roxmltree::ParsingOptions {
        allow_dtd: false,
        nodes_limit: MAX_XML_NODES,
    };
    let doc = roxmltree::Document::parse_with_options(text, options)
        .map_err(|e| format_err(path, "OME-XML", format!("invalid XML: {e}")))?;
    let root = doc.root_element();
    if root.tag_name().name() != "OME" {
        return Err(format_err(
            path,
            "OME-XML",
            format!(
                "the root element is <{}>, not <OME>",
                root.tag_name().name()
            ),
        ));
    }
    let mut images = Vec::new();
    for (i, image) in root
        .children()
        .filter(|n| n.is_element() && n.tag_name().name() == "Image")
        .enumerate()
    {
        let Some(pixels) = image
            .children()
            .find(|n| n.is_element() && n.tag_name().name() == "Pixels")
        else {
            return Err(format_err(
                path,
                "Pixels",
                format!("Image {i} has no Pixels element"),
            ));
        };
        images.push(parse_pixels(path, i, pixels)?);
    }
    if images.is_empty() {
        return Err(format_err(path, "Image", "the OME-XML holds no Image"));
    }
    Ok(OmeXml { images })
}

/// Parses one `Pixels` element (of `Image` number `image`).
fn parse_pixels(
    path: &Path,
    image: usize,
    pixels: roxmltree::Node<'_, '_>,
) -> Result<OmePixels, VolumeError> {
    let attr = |name: &str| pixels.attribute(name);
    let size_of = |name: &str| -> Result<u64, VolumeError> {
        let text = attr(name).ok_or_else(|| {
            format_err(path, name, format!("Image {image}: Pixels has no {name}"))
        })?;
        match text.trim().parse::<u64>() {
            Ok(n) if n >= 1 => Ok(n),
            _ => Err(format_err(
                path,
                name,
                format!("Image {image}: {name} = {text:?}, expected a positive integer"),
            )),
        }
    };
    let size = [
        size_of("SizeX")?,
        size_of("SizeY")?,
        size_of("SizeZ")?,
        size_of("SizeC")?,
        size_of("SizeT")?,
    ];
    let order_text = attr("DimensionOrder").unwrap_or("XYZCT");
    let dimension_order = DimensionOrder::parse(order_text).ok_or_else(|| {
        format_err(
            path,
            "DimensionOrder",
            format!(
                "Image {image}: {order_text:?}, expected XYZCT, XYZTC, XYCZT, XYCTZ, XYTZC or XYTCZ"
            ),
        )
    })?;
    let type_name = attr("Type").unwrap_or("").to_string();
    let stored = StoredType::parse(&type_name);
    let mut physical_um = [None; 3];
    for (slot, axis) in physical_um.iter_mut().zip(["X", "Y", "Z"]) {
        let name = format!("PhysicalSize{axis}");
        let Some(text) = attr(&name) else { continue };
        let value = match text.trim().parse::<f64>() {
            Ok(v) if v.is_finite() && v > 0.0 => v,
            _ => {
                return Err(format_err(
                    path,
                    &name,
                    format!("Image {image}: {name} = {text:?}, expected a positive number"),
                ))
            }
        };
        let unit_name = format!("{name}Unit");
        let unit = attr(&unit_name).unwrap_or("µm");
        let factor = micrometres_per(unit).ok_or_else(|| {
            format_err(
                path,
                &unit_name,
                format!(
                    "Image {image}: unit {unit:?} is not a length unit mixvol knows (m, cm, mm, \
                     µm, nm, pm, Å, ...)"
                ),
            )
        })?;
        let um = value * factor;
        if !(um.is_finite() && um > 0.0 && (um as f32).is_normal()) {
            return Err(format_err(
                path,
                &name,
                format!("Image {image}: {value} {unit} is out of range"),
            ));
        }
        *slot = Some(um);
    }
    let mut tiff_data = Vec::new();
    for node in pixels
        .children()
        .filter(|n| n.is_element() && n.tag_name().name() == "TiffData")
    {
        let number = |name: &str| -> Result<Option<u64>, VolumeError> {
            node.attribute(name)
                .map(|t| {
                    t.trim().parse::<u64>().map_err(|_| {
                        format_err(
                            path,
                            "TiffData",
                            format!("Image {image}: TiffData {name} = {t:?}, expected an integer"),
                        )
                    })
                })
                .transpose()
        };
        let ifd = number("IFD")?;
        let file_name = node
            .children()
            .find(|n| n.is_element() && n.tag_name().name() == "UUID")
            .and_then(|u| u.attribute("FileName"))
            .map(str::to_string);
        tiff_data.push(TiffData {
            ifd: ifd.unwrap_or(0),
            ifd_given: ifd.is_some(),
            first: [
                number("FirstZ")?.unwrap_or(0),
                number("FirstC")?.unwrap_or(0),
                number("FirstT")?.unwrap_or(0),
            ],
            plane_count: number("PlaneCount")?,
            file_name,
        });
    }
    Ok(OmePixels {
        size,
        dimension_order,
        stored,
        type_name,
        physical_um,
        tiff_data,
    })
}

/// Micrometres in one `unit` (OME's `UnitsLength` symbols); `None` for units that are not
/// lengths (`pixel`, `reference frame`) or not known.
pub(super) fn micrometres_per(unit: &str) -> Option<f64> {
    Some(match unit.trim() {
        "km" => 1e9,
        "m" => 1e6,
        "dm" => 1e5,
        "cm" => 1e4,
        "mm" => 1e3,
        // Micro sign (U+00B5), Greek mu (U+03BC), and the ASCII spellings.
        "µm" | "μm" | "um" | "micron" | "microns" => 1.0,
        "nm" => 1e-3,
        "pm" => 1e-6,
        // Latin capital A with ring (U+00C5) and the angstrom sign (U+212B).
        "\u{c5}" | "\u{212b}" => 1e-4,
        "in" => 25_400.0,
        "mil" | "thou" => 25.4,
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dimension_orders_index_planes() {
        let sizes = [4, 3, 2];
        let o = DimensionOrder::parse("XYZCT").unwrap();
        assert_eq!(o.plane_index([1, 2, 1], sizes), Some(1 + 4 * (2 + 3)));
        let o = DimensionOrder::parse("XYCZT").unwrap();
        assert_eq!(o.plane_index([1, 2, 1], sizes), Some(2 + 3 * (1 + 4)));
        assert_eq!(o.name(), "XYCZT");
        assert!(DimensionOrder::parse("XYZZT").is_none());
        assert!(DimensionOrder::parse("XYZC").is_none());
    }

    #[test]
    fn tiff_data_maps_planes_and_units_convert() {
        let xml = br#"<?xml version="1.0"?>
<OME xmlns="http://www.openmicroscopy.org/Schemas/OME/2016-06">
 <Image ID="Image:0"><Pixels ID="Pixels:0" DimensionOrder="XYCZT" Type="uint16"
   SizeX="8" SizeY="6" SizeZ="5" SizeC="2" SizeT="1"
   PhysicalSizeX="0.5" PhysicalSizeY="500" PhysicalSizeYUnit="nm" PhysicalSizeZ="0.002"
   PhysicalSizeZUnit="mm">
  <TiffData IFD="3" PlaneCount="10"/>
 </Pixels></Image>
</OME>"#;
        let p = Path::new("t.ome.tif");
        let ome = parse_ome_xml(p, xml).unwrap();
        let px = &ome.images[0];
        assert_eq!(px.size, [8, 6, 5, 2, 1]);
        assert_eq!(px.stored, Some(StoredType::U16));
        assert_eq!(px.physical_um, [Some(0.5), Some(0.5), Some(2.0)]);
        // XYCZT: plane (z=2, c=1) is index 1 + 2 * 2 = 5, in IFD 3 + 5.
        assert_eq!(px.ifd_of(p, [2, 1, 0]).unwrap(), Some(8));
        let bad = br#"<OME><Image><Pixels SizeX="1" SizeY="1" SizeZ="0" SizeC="1" SizeT="1"/></Image></OME>"#;
        match parse_ome_xml(p, bad) {
            Err(VolumeError::Format { field, .. }) => assert_eq!(field, "SizeZ"),
            other => panic!("{other:?}"),
        }
    }
}
