// Writes a NIfTI-1 or -2 file with nifticlib itself (an independent writer for the reader tests).
#pragma once
#include <gtest/gtest.h>
#include <nifti2_io.h>

#include <cstring>
#include <string>

#include "adaptiso/volume.hpp"

namespace testutil {
using adaptiso::ScalarType;
using adaptiso::Volume;

inline void write_nifti(const std::string& path, const Volume& ref, int version, double slope, double inter) {
  int64_t dims[8] = {3, ref.dims[0], ref.dims[1], ref.dims[2], 1, 1, 1, 1};
  int dt = ref.type == ScalarType::i16 ? DT_INT16 : ref.type == ScalarType::u8 ? DT_UINT8 : DT_FLOAT32;
  nifti_image* nim = nifti_make_new_nim(dims, dt, 1);
  ASSERT_NE(nim, nullptr);
  std::memcpy(nim->data, ref.bytes.data(), ref.bytes.size());
  nim->nifti_type = version == 2 ? NIFTI_FTYPE_NIFTI2_1 : NIFTI_FTYPE_NIFTI1_1;
  nim->scl_slope = slope;
  nim->scl_inter = inter;
  nim->dx = nim->pixdim[1] = 0.5;
  nim->dy = nim->pixdim[2] = 0.75;
  nim->dz = nim->pixdim[3] = 2.0;
  ASSERT_EQ(nifti_set_filenames(nim, path.c_str(), 0, 1), 0);
  nifti_image_write(nim);
  nifti_image_free(nim);
}

}  // namespace testutil
