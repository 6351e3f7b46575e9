// 16-lane float and 8-lane double vectors shared by the compiled kernels (GCC vector extensions: one zmm
// register with AVX-512, two ymm with AVX2). Written with explicit vectors rather than relying on
// auto-vectorisation, which silently fell back to scalar code.
#pragma once

#include <cstdint>

namespace go_simd {

typedef float vf __attribute__((vector_size(64)));
typedef int32_t vi __attribute__((vector_size(64)));
typedef double vd __attribute__((vector_size(64)));   // 8 lanes
typedef int64_t vl __attribute__((vector_size(64)));  // comparison masks of vd

// Whether any lane of a comparison mask (lanes 0 or -1) is set.
inline bool vany(vi m) {
  int32_t acc = 0;
  for (int k = 0; k < 16; ++k) acc |= m[k];
  return acc != 0;
}

}  // namespace go_simd
