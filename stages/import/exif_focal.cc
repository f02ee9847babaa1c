// Focal length in pixels from EXIF (libexif): the 35 mm equivalent focal length when present
// (f_px = f35 / 36 * max(w, h), 36 mm being the width of a 35 mm frame), else the focal length in
// mm times the focal-plane resolution (pixels per unit) when the camera wrote it. Also the EXIF
// orientation tag.
#include <libexif/exif-data.h>

#include <algorithm>
#include <string>

#include "stages/import/import.h"

namespace ibmr {

namespace {

bool RationalTag(ExifData* data, ExifTag tag, double* value) {
  ExifEntry* entry = exif_data_get_entry(data, tag);
  if (!entry || entry->components < 1) return false;
  const ExifByteOrder order = exif_data_get_byte_order(data);
  if (entry->format == EXIF_FORMAT_RATIONAL) {
    const ExifRational r = exif_get_rational(entry->data, order);
    if (r.denominator == 0) return false;
    *value = static_cast<double>(r.numerator) / r.denominator;
    return true;
  }
  if (entry->format == EXIF_FORMAT_SHORT) {
    *value = exif_get_short(entry->data, order);
    return true;
  }
  return false;
}

}  // namespace

double ExifFocalPixels(const std::string& image_path, int width, int height) {
  ExifData* data = exif_data_new_from_file(image_path.c_str());
  if (!data) return 0;
  double focal_pixels = 0;
  double f35 = 0, f_mm = 0, resolution = 0, unit = 0;
  if (RationalTag(data, EXIF_TAG_FOCAL_LENGTH_IN_35MM_FILM, &f35) && f35 > 0) {
    focal_pixels = f35 / 36.0 * std::max(width, height);
  } else if (RationalTag(data, EXIF_TAG_FOCAL_LENGTH, &f_mm) && f_mm > 0 &&
             RationalTag(data, EXIF_TAG_FOCAL_PLANE_X_RESOLUTION, &resolution) && resolution > 0) {
    // Resolution unit: 2 inches (the default), 3 centimetres, 4 millimetres.
    const double mm_per_unit = !RationalTag(data, EXIF_TAG_FOCAL_PLANE_RESOLUTION_UNIT, &unit) || unit == 2 ? 25.4
                               : unit == 3                                                               ? 10.0
                                                                                                         : 1.0;
    focal_pixels = f_mm * resolution / mm_per_unit;
  }
  exif_data_unref(data);
  return focal_pixels;
}

int ExifOrientation(const std::string& image_path) {
  ExifData* data = exif_data_new_from_file(image_path.c_str());
  if (!data) return 1;
  double value = 1;
  const bool found = RationalTag(data, EXIF_TAG_ORIENTATION, &value);
  exif_data_unref(data);
  return found && value >= 1 && value <= 8 ? static_cast<int>(value) : 1;
}

}  // namespace ibmr
