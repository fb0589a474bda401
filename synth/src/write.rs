//! Writing rendered frames through GDAL, in the formats the pipeline reads.

use std::path::Path;

use gdal::raster::{Buffer, ColorInterpretation, RasterCreationOptions};
use gdal::spatial_ref::SpatialRef;
use gdal::{Dataset, DriverManager};

use super::{Error, GreyImage};

/// How a grey image is stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SampleFormat {
    /// 8-bit RGB JPEG, quality 95.
    Jpeg,
    /// 8-bit RGB PNG (deflate level 1).
    Png,
    /// 8-bit RGB GeoTIFF.
    GtiffRgb8,
    /// 16-bit 4-band multispectral GeoTIFF (R, G, B, NIR; tiled 256x256): the
    /// NIR band is the inverse of the picture, so a reader that took it
    /// instead of the RGB bands would find nothing.
    Gtiff16Rgbn,
    /// 8-bit grey plus alpha PNG.
    PngGreyAlpha,
}

/// An affine georeference with an EPSG CRS.
#[derive(Debug, Clone, PartialEq)]
pub struct GeoSpec {
    pub geotransform: [f64; 6],
    pub epsg: u32,
}

/// Writes `img` to `path` in `format`, with `geo` when given (GeoTIFF only).
pub fn write_image(
    path: &Path,
    img: &GreyImage,
    format: SampleFormat,
    geo: Option<&GeoSpec>,
) -> Result<(), Error> {
    write_inner(path, img, format, geo).map_err(|source| Error::Gdal {
        path: path.to_path_buf(),
        source,
    })
}

fn write_inner(
    path: &Path,
    img: &GreyImage,
    format: SampleFormat,
    geo: Option<&GeoSpec>,
) -> gdal::errors::Result<()> {
    let (w, h) = (img.width, img.height);
    let to_u8 = |v: f32| (v * 255.0).round().clamp(0.0, 255.0) as u8;
    match format {
        SampleFormat::Gtiff16Rgbn => {
            let driver = DriverManager::get_driver_by_name("GTiff")?;
            let options =
                RasterCreationOptions::from_iter(["TILED=YES", "BLOCKXSIZE=256", "BLOCKYSIZE=256"]);
            let mut ds =
                driver.create_with_band_type_with_options::<u16, _>(path, w, h, 4, &options)?;
            // 12-bit sensor range with a dark offset, as multispectral cameras deliver.
            let picture: Vec<u16> = img
                .data
                .iter()
                .map(|v| (600.0 + v * 3000.0).round() as u16)
                .collect();
            let nir: Vec<u16> = img
                .data
                .iter()
                .map(|v| (3600.0 - v * 3000.0).round() as u16)
                .collect();
            let interps = [
                ColorInterpretation::RedBand,
                ColorInterpretation::GreenBand,
                ColorInterpretation::BlueBand,
                ColorInterpretation::Undefined,
            ];
            for (i, interp) in interps.into_iter().enumerate() {
                let mut band = ds.rasterband(i + 1)?;
                let data = if i == 3 { nir.clone() } else { picture.clone() };
                band.write((0, 0), (w, h), &mut Buffer::new((w, h), data))?;
                band.set_color_interpretation(interp)?;
            }
            set_geo(&mut ds, geo)
        }
        SampleFormat::GtiffRgb8 => {
            let driver = DriverManager::get_driver_by_name("GTiff")?;
            let mut ds = driver.create_with_band_type::<u8, _>(path, w, h, 3)?;
            let bytes: Vec<u8> = img.data.iter().map(|&v| to_u8(v)).collect();
            for i in 1..=3 {
                ds.rasterband(i)?
                    .write((0, 0), (w, h), &mut Buffer::new((w, h), bytes.clone()))?;
            }
            set_geo(&mut ds, geo)
        }
        SampleFormat::Jpeg | SampleFormat::Png | SampleFormat::PngGreyAlpha => {
            let bands = if format == SampleFormat::PngGreyAlpha {
                2
            } else {
                3
            };
            let mem = DriverManager::get_driver_by_name("MEM")?;
            let ds = mem.create_with_band_type::<u8, _>("", w, h, bands)?;
            let bytes: Vec<u8> = img.data.iter().map(|&v| to_u8(v)).collect();
            if bands == 2 {
                ds.rasterband(1)?
                    .write((0, 0), (w, h), &mut Buffer::new((w, h), bytes))?;
                let mut alpha = ds.rasterband(2)?;
                alpha.write((0, 0), (w, h), &mut Buffer::new((w, h), vec![255u8; w * h]))?;
                alpha.set_color_interpretation(ColorInterpretation::AlphaBand)?;
            } else {
                for i in 1..=3 {
                    ds.rasterband(i)?.write(
                        (0, 0),
                        (w, h),
                        &mut Buffer::new((w, h), bytes.clone()),
                    )?;
                }
            }
            let (name, options) = match format {
                SampleFormat::Jpeg => ("JPEG", RasterCreationOptions::from_iter(["QUALITY=95"])),
                // Test frames are read once: the least deflate effort
                // (the pixels are the same at any level).
                _ => ("PNG", RasterCreationOptions::from_iter(["ZLEVEL=1"])),
            };
            let driver = DriverManager::get_driver_by_name(name)?;
            ds.create_copy(&driver, path, &options)?;
            Ok(())
        }
    }
}

fn set_geo(ds: &mut Dataset, geo: Option<&GeoSpec>) -> gdal::errors::Result<()> {
    if let Some(geo) = geo {
        ds.set_geo_transform(&geo.geotransform)?;
        ds.set_spatial_ref(&SpatialRef::from_epsg(geo.epsg)?)?;
    }
    Ok(())
}
