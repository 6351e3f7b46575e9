// Tile-based Gaussian rasterizer for the CPU: binning, forward compositing and its hand-written backward.
//
// The maths is documented in docs/rendering.md and mirrors go_core/render/reference.py exactly.
// Parallel over 16x16 tiles (OpenMP, dynamic schedule, at::get_num_threads() threads); inside a tile a row
// of 16 pixels is one 16-lane vector step with a branch-free exp where AVX-512 exists, else two 8-lane
// steps; one 8-lane step where a Gaussian can reach only one half of the row (82% of the evaluated rows on a
// trained 27k-Gaussian model); the backward takes a row that both halves need as two 8-lane steps.
// Every tile is processed by one thread and per-Gaussian gradients are summed in a fixed order, so results
// are bit-identical across runs and thread counts.

#include <torch/extension.h>
#include <ATen/Parallel.h>
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <memory>
#include <vector>

#include "simd.h"

#ifdef __AVX512F__
#include <immintrin.h>
#endif

namespace {

constexpr int TILE = 16;
constexpr int NPIX = TILE * TILE;
constexpr int HALF = TILE / 2;
constexpr float ALPHA_MIN = 1.0f / 255.0f;
constexpr float ALPHA_MAX = 0.99f;
constexpr int NP = 16;   // packed floats per Gaussian: mx my a b c o f0..f3 log(255 o) det/a b/a 1/a (pad)
constexpr int NG = 10;   // gradient floats per (tile, Gaussian): dmx dmy da db dc do df0..df3

using go_simd::vany;
using go_simd::vf;
using go_simd::vi;
static const vf LANE = {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15};

typedef float vh __attribute__((vector_size(32)));    // half a tile row: 8 lanes
typedef int32_t vih __attribute__((vector_size(32)));
static const vh HLANE = {0, 1, 2, 3, 4, 5, 6, 7};

// Offsets dx = mx - x of a tile row's pixel centres from a Gaussian's centre, and their squares, by half
// row: lane k of half h is pixel HALF*h + k. dx0 is the offset of the row's first pixel.
struct HalfRowDx {
  vh dx[2], dx2[2];
  explicit HalfRowDx(float dx0)
      : dx{dx0 - HLANE, dx0 - (HLANE + float(HALF))}, dx2{dx[0] * dx[0], dx[1] * dx[1]} {}
};

static inline vf splat(float x) { return vf{} + x; }
static inline vi splati(int32_t x) { return vi{} + x; }
template <class V>
static inline V vmin(V a, V b) { return a < b ? a : b; }
template <class V>
static inline V vmax(V a, V b) { return a > b ? a : b; }
// Lane k of a tile-row vector: loads and stores of part of the row start there.
static inline float* lane_ptr(vf& v, int k) { return reinterpret_cast<float*>(&v) + k; }
static inline int32_t* lane_ptr(vi& v, int k) { return reinterpret_cast<int32_t*>(&v) + k; }
template <class V>
static inline V ld(const void* p) {
  V v;
  std::memcpy(&v, p, sizeof(V));
  return v;
}
template <class V>
static inline void st(void* p, V v) { std::memcpy(p, &v, sizeof(V)); }

// floor(t) for |t| < 2^23, and y * 2^e for an integral e in [-126, 127]. With AVX-512 one instruction each
// (vrndscaleps, vscalefps); otherwise through integer conversions. Both forms round identically (floor is
// exact; scaling by a power of two is one correctly rounded product), so results do not depend on the ISA.
template <class V>
static inline V vfloor(V t) {
#ifdef __AVX512F__
  if constexpr (sizeof(V) == 64) return (V)_mm512_roundscale_ps((__m512)t, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
#endif
#if defined(__AVX512F__) && defined(__AVX512VL__)
  if constexpr (sizeof(V) == 32) return (V)_mm256_roundscale_ps((__m256)t, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
#endif
  using VI = decltype(t < t);
  const V fi = __builtin_convertvector(__builtin_convertvector(t, VI), V);
  return fi > t ? fi - 1.0f : fi;
}
template <class V>
static inline V vscale2(V y, V e) {
#ifdef __AVX512F__
  if constexpr (sizeof(V) == 64) return (V)_mm512_scalef_ps((__m512)y, (__m512)e);
#endif
#if defined(__AVX512F__) && defined(__AVX512VL__)
  if constexpr (sizeof(V) == 32) return (V)_mm256_scalef_ps((__m256)y, (__m256)e);
#endif
  using VI = decltype(y < y);
  return y * (V)((__builtin_convertvector(e, VI) + 127) << 23);
}

// exp(x) for x <= 0 (clamped below at -87): Cody-Waite range reduction and the Cephes degree-6 polynomial,
// about 1 ulp, branch-free.
template <class V>
static inline V vexp_neg(V x) {
  x = vmax(x, V{} - 87.0f);
  const V t = x * 1.44269504088896341f + 0.5f;
  const V fi = vfloor(t);
  V r = x - fi * 0.693359375f;
  r = r + fi * 2.12194440e-4f;
  V p = V{} + 1.9875691500e-4f;
  p = p * r + 1.3981999507e-3f;
  p = p * r + 8.3334519073e-3f;
  p = p * r + 4.1665795894e-2f;
  p = p * r + 1.6666665459e-1f;
  p = p * r + 5.0000001201e-1f;
  const V y = p * r * r + r + 1.0f;
  return vscale2(y, fi);
}

// Lane sums of several vectors at once, through a transposition tree: each fold adds the lane pairs of two
// vectors and packs both results into one vector, halving the lanes per source vector. Every source vector
// is summed in the same fixed order (deterministic): (l0..7 + l8..15), then (0..3 + 4..7), then
// (b0 + b2) + (b1 + b3). Ten sums cost 33 vector operations instead of ~90 for ten separate reductions.
static inline vf fold8(const vh* u, const vh* v) {  // u, v as halves: [u_lo + u_hi | v_lo + v_hi]
  return __builtin_shufflevector(u[0] + u[1], v[0] + v[1], 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
}
static inline vf fold4(vf p, vf q) {  // each 8-lane group g: g0..3 + g4..7
  return __builtin_shufflevector(p, q, 0, 1, 2, 3, 8, 9, 10, 11, 16, 17, 18, 19, 24, 25, 26, 27) +
         __builtin_shufflevector(p, q, 4, 5, 6, 7, 12, 13, 14, 15, 20, 21, 22, 23, 28, 29, 30, 31);
}
static inline vf fold2(vf r, vf s) {  // each 4-lane group g: (g0 + g2, g1 + g3)
  return __builtin_shufflevector(r, s, 0, 1, 4, 5, 8, 9, 12, 13, 16, 17, 20, 21, 24, 25, 28, 29) +
         __builtin_shufflevector(r, s, 2, 3, 6, 7, 10, 11, 14, 15, 18, 19, 22, 23, 26, 27, 30, 31);
}
static inline vf fold1(vf e, vf f) {  // each lane pair: e + o
  return __builtin_shufflevector(e, f, 0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30) +
         __builtin_shufflevector(e, f, 1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 27, 29, 31);
}

// out[k] = sum of the 16 lanes of v[k] (held as two 8-lane halves), k < NG (= 10).
static inline void hsum_rows(const vh (*v)[2], float* out) {
  static_assert(NG == 10, "the tree below pairs ten vectors");
  const vf z{};
  const vf a0 = fold8(v[0], v[1]), a1 = fold8(v[2], v[3]), a2 = fold8(v[4], v[5]), a3 = fold8(v[6], v[7]);
  const vf a4 = fold8(v[8], v[9]);
  const vf b0 = fold4(a0, a1), b1 = fold4(a2, a3), b2 = fold4(a4, z);
  const vf sums = fold1(fold2(b0, b1), fold2(b2, z));  // lane k: the sum of v[k]
  std::memcpy(out, &sums, NG * sizeof(float));
}

// Order-preserving unsigned key of a float (negative values flip all bits, positive ones the sign bit).
static inline uint32_t float_key(float f) {
  uint32_t u;
  std::memcpy(&u, &f, sizeof(float));
  return (u & 0x80000000u) ? ~u : (u | 0x80000000u);
}

// Stable LSD radix sort of `ids` by depth (ties keep index order).
static void sort_by_depth(std::vector<int32_t>& ids, const float* depth) {
  const size_t n = ids.size();
  std::vector<uint32_t> keys(n), keys2(n);
  std::vector<int32_t> ids2(n);
  for (size_t i = 0; i < n; ++i) keys[i] = float_key(depth[ids[i]]);
  for (int shift = 0; shift < 32; shift += 8) {
    size_t count[257] = {0};
    for (size_t i = 0; i < n; ++i) count[((keys[i] >> shift) & 255u) + 1]++;
    for (int b = 0; b < 256; ++b) count[b + 1] += count[b];
    for (size_t i = 0; i < n; ++i) {
      const size_t dst = count[(keys[i] >> shift) & 255u]++;
      keys2[dst] = keys[i];
      ids2[dst] = ids[i];
    }
    keys.swap(keys2);
    ids.swap(ids2);
  }
}

struct Rect {
  int x0, x1, y0, y1;
};

// Same float32 arithmetic as go_core/render/tiles.py::tile_rects.
static inline Rect tile_rect(float mx, float my, int32_t radius, int tiles_x, int tiles_y) {
  const float r = static_cast<float>(radius);
  auto clampi = [](float v, int hi) { return static_cast<int>(std::min(std::max(v, 0.0f), float(hi))); };
  return {clampi(std::floor((mx - r) / TILE), tiles_x), clampi(std::ceil((mx + r) / TILE), tiles_x),
          clampi(std::floor((my - r) / TILE), tiles_y), clampi(std::ceil((my + r) / TILE), tiles_y)};
}

// Half-width, with the margins that cover the float rounding of the per-pixel evaluation, of the interval of
// a pixel row where sigma <= thr: sqrt(q / a), q = 2 thr - dy² det/a (see rows_may_hit). Shared by the row
// test and the binning's strip bounds so that both keep the same margins.
static inline float reach_half_width(float q, float inv_a) {
  return std::sqrt(std::max(q, 0.0f) * inv_a) * 1.0001f + 0.01f;
}

// Conservative test whether a pixel of the 16-pixel tile row at offset dy = my - y (pixel centres x0+0.5 ..
// x0+15.5) can reach alpha >= 1/255, i.e. sigma <= log(255 o). Along the row sigma(dx) is a parabola; its
// sub-threshold interval of pixel x is centre mx + (b/a) dy, half-width sqrt((2 thr - dy² det/a) / a).
// The margins cover the float rounding of the per-pixel evaluation, so skipping never changes a result.
// Evaluated for the 16 rows of a tile at once (one SIMD loop); per row r, bit 0 of hit[r] is set where a
// pixel of its left half (x0+0.5 .. x0+7.5) may be touched, bit 1 for the right half (x0+8.5 .. x0+15.5).
static inline void rows_may_hit(const float* g, float x0, float y0, int32_t* hit) {
  const float mx = g[0], my = g[1], cc = g[4], lthr = g[10], det_a = g[11], b_a = g[12], inv_a = g[13];
#pragma omp simd
  for (int r = 0; r < TILE; ++r) {
    const float dy = my - (y0 + float(r) + 0.5f);
    const float dy2 = dy * dy;
    const float thr = lthr + 1e-2f + 1e-5f * cc * dy2;
    const float q = 2.0f * thr - det_a * dy2;
    const float hw = reach_half_width(q, inv_a);
    const float cx = mx + b_a * dy;
    const int lo = (cx + hw >= x0 + 0.5f) & (cx - hw <= x0 + (HALF - 0.5f));
    const int hi = (cx + hw >= x0 + (HALF + 0.5f)) & (cx - hw <= x0 + (TILE - 0.5f));
    hit[r] = -static_cast<int>(q >= 0.0f) & (lo | (hi << 1));
  }
}

// Conservative x-ranges, per tile row, of the pixels a Gaussian can reach with alpha >= 1/255: the x-extent,
// within each 16-pixel strip, of the region rows_may_hit tests, in O(1) per strip instead of per row. Its
// threshold thr(v) = T0 + 1e-5 c v² (v = my - y, T0 = log(255 o) + 1e-2) is bounded by the constant
// T = T0 / (1 - 2e-5 c / (det/a)) on every row it can reach (|v| <= V = sqrt(2T a / det)), so the region lies
// inside the ellipse 0.5 (a u² + 2 b u v + c v²) <= T. Its right edge x(v) = mx + (b/a) v + hw(v) is concave,
// its left edge convex, so their extremes over a strip lie at v = ±b sqrt(2T / (det c)) clamped to the strip.
// Same margins as rows_may_hit plus 0.05 px. Degenerate, NaN or far-off (> 1e5 px) input keeps whole rows.
struct StripSpans {
  bool keep_all = true;
  float mx = 0, my = 0, b_a = 0, inv_a = 0, det_a = 0, T2 = 0, V = 0, vr = 0, xr = 0;

  explicit StripSpans(const float* g) {
    const float a = g[2], b = g[3], c = g[4];
    det_a = g[11];
    mx = g[0];
    my = g[1];
    // (comparisons are false for NaN); beyond 1e5 px float rounding could exceed the margins
    if (!(det_a > 0.0f && a > 0.0f && c > 0.0f && std::fabs(mx) < 1e5f && std::fabs(my) < 1e5f)) return;
    const float k = 1.0f - 2e-5f * c / det_a;
    if (!(k > 0.5f)) return;  // anisotropy beyond ~1e4: not worth bounding
    b_a = g[12];
    inv_a = g[13];
    T2 = 2.0f * (g[10] + 1e-2f) / k;
    V = std::sqrt(T2 / det_a) * 1.0001f + 0.01f;
    vr = b * std::sqrt(T2 / (det_a * a * c));
    xr = half_width(vr);
    keep_all = !(V < 1e30f && std::fabs(vr) < 1e30f && xr < 1e30f);
  }

  float half_width(float v) const { return reach_half_width(T2 - det_a * v * v, inv_a); }

  // x-range of the strip of pixel rows y0+0.5 .. y0+15.5; lo > hi: out of reach.
  void range(float y0, float& lo, float& hi) const {
    lo = -1e30f;
    hi = 1e30f;
    if (keep_all) return;
    const float v0 = std::max(my - (y0 + (TILE - 0.5f)), -V), v1 = std::min(my - (y0 + 0.5f), V);
    if (v0 > v1) {
      lo = 1e30f;
      hi = -1e30f;
      return;
    }
    const float v_right = std::min(std::max(vr, v0), v1), v_left = std::min(std::max(-vr, v0), v1);
    lo = mx + b_a * v_left - (v_left == -vr ? xr : half_width(v_left)) - 0.05f;
    hi = mx + b_a * v_right + (v_right == vr ? xr : half_width(v_right)) + 0.05f;
  }
};

template <typename F>
static void parallel_dynamic(int64_t n, F&& f) {
  const int nt = std::max(1, std::min<int>(at::get_num_threads(), static_cast<int>(std::max<int64_t>(n, 1))));
#pragma omp parallel for schedule(dynamic, 1) num_threads(nt)
  for (int64_t i = 0; i < n; ++i) f(i);
}

}  // namespace

// Binning. The four composited features come as colours [C,N,3] and a fourth channel [C,N] (the render's
// depths: no concatenation, and separate gradients in the backward). Returns (params [C*N,16],
// tile_offsets [C*T+1] i64, isect_gid [M] i32 (camera-local ids), gauss_offsets [C*N+1] i64,
// gauss_isects [M] i64 (positions of each Gaussian's intersections, in row-major tile order)).
//
// Four parallel passes. (1) Over Gaussians in index order: pack the parameters, find the tile rectangle and
// the tiles within it that the Gaussian can reach. (2) Per camera: sort the binned Gaussians by depth.
// (3) Over chunks of that depth order: count the tiles each chunk touches and list them in the chunk's own
// buffer. (4) The same chunks scatter their Gaussians into the tiles, each from its own cursors (prefix sums
// of the counts in chunk order), so every tile lists its Gaussians in depth order whatever the thread count.
// Passes 3 and 4 read each Gaussian's data once, not once per tile row band: depth order is random in memory.
std::vector<torch::Tensor> bin_and_pack(torch::Tensor means2d, torch::Tensor conics, torch::Tensor colors,
                                        torch::Tensor feat4, torch::Tensor opacities, torch::Tensor depths,
                                        torch::Tensor radii, int64_t width, int64_t height) {
  const int64_t C = means2d.size(0), N = means2d.size(1), CN = C * N;
  const int tiles_x = static_cast<int>((width + TILE - 1) / TILE);
  const int tiles_y = static_cast<int>((height + TILE - 1) / TILE);
  const int64_t T = int64_t(tiles_x) * tiles_y;
  const float* m2 = means2d.data_ptr<float>();
  const float* con = conics.data_ptr<float>();
  const float* col = colors.data_ptr<float>();  // [C,N,3]: the first three composited features
  const float* f4 = feat4.data_ptr<float>();     // [C,N]: the fourth (the render passes the depths)
  const float* op = opacities.data_ptr<float>();
  const float* dp = depths.data_ptr<float>();
  const int32_t* rad = radii.data_ptr<int32_t>();
  const int threads = std::max(1, at::get_num_threads());

  auto fopt = torch::TensorOptions().dtype(torch::kFloat32);
  auto lopt = torch::TensorOptions().dtype(torch::kInt64);
  torch::Tensor params = torch::empty({CN, NP}, fopt);
  float* P = params.data_ptr<float>();
  torch::Tensor goff_t = torch::empty({CN + 1}, lopt);
  int64_t* goff = goff_t.data_ptr<int64_t>();

  // (1) The 3-sigma rectangle is only a candidate set: about half of its tiles are typically out of reach
  // (its corners, the ellipse's thin side, low opacity). In every tile row keep only the tiles that
  // StripSpans' x-range overlaps. Dropping the others changes no result (the compositing would skip every
  // pixel row of such a pair) and saves their cost in the forward, the backward and the gradient reduction.
  // Each chunk of Gaussians keeps its rows' tile ranges in its own buffer (no prefix sum needed first).
  struct Span {
    int32_t x0, x1;  // kept tiles of one rectangle row
  };
  struct Binned {
    Rect rect;
    const Span* rows;  // rect.y1 - rect.y0 entries
  };
  std::unique_ptr<Binned[]> bins(new Binned[std::max<int64_t>(CN, 1)]);
  const int64_t pack_chunks = std::max<int64_t>(1, std::min<int64_t>(4 * threads, CN / 512));
  std::vector<std::vector<Span>> span_bufs(pack_chunks);
  parallel_dynamic(pack_chunks, [&](int64_t k) {
    const int64_t b = CN * k / pack_chunks, e = CN * (k + 1) / pack_chunks;
    int64_t rows_total = 0;
    for (int64_t i = b; i < e; ++i) {
      float* g = P + i * NP;
      g[0] = m2[2 * i];
      g[1] = m2[2 * i + 1];
      g[2] = con[3 * i];
      g[3] = con[3 * i + 1];
      g[4] = con[3 * i + 2];
      g[5] = op[i];
      for (int q = 0; q < 3; ++q) g[6 + q] = col[3 * i + q];
      g[9] = f4[i];
      const double det = double(g[2]) * g[4] - double(g[3]) * g[3];
      // log(255 o): sigma above it gives alpha < 1/255; negative flags Gaussians that never reach 1/255
      g[10] = g[5] >= ALPHA_MIN ? std::max(0.0f, std::log(g[5] * 255.0f)) : -1.0f;
      const bool pd = g[2] > 0.0f && det > 0.0;
      g[11] = pd ? static_cast<float>(det / g[2]) : 0.0f;
      g[12] = pd ? g[3] / g[2] : 0.0f;
      g[13] = pd ? 1.0f / g[2] : 1e30f;
      g[14] = g[15] = 0.0f;
      Rect r{0, 0, 0, 0};
      if (rad[i] > 0 && g[10] >= 0.0f) r = tile_rect(g[0], g[1], rad[i], tiles_x, tiles_y);
      if (r.x1 <= r.x0 || r.y1 <= r.y0) r = Rect{0, 0, 0, 0};
      bins[i].rect = r;
      rows_total += r.y1 - r.y0;
    }
    std::vector<Span>& buf = span_bufs[k];
    buf.resize(rows_total);
    Span* sp = buf.data();
    for (int64_t i = b; i < e; ++i) {
      const Rect& r = bins[i].rect;
      bins[i].rows = sp;
      int64_t kept = 0;
      if (r.y1 > r.y0) {
        const StripSpans strips(P + i * NP);
        for (int y = r.y0; y < r.y1; ++y, ++sp) {
          float span_lo, span_hi;
          strips.range(float(y * TILE), span_lo, span_hi);
          // tile x is touched by some row iff span_hi >= 16x + 0.5 and span_lo <= 16x + 15.5
          const float fx0 = std::ceil((span_lo - (TILE - 0.5f)) / TILE);
          const float fx1 = std::floor((span_hi - 0.5f) / TILE) + 1.0f;
          // clamped to the rectangle; a NaN bound keeps the whole rectangle row (NaN comparisons are false)
          const int x0 = fx0 > float(r.x0) ? static_cast<int>(std::min(fx0, float(r.x1))) : r.x0;
          const int x1 = fx1 < float(r.x1) ? static_cast<int>(std::max(fx1, float(x0))) : r.x1;
          *sp = {x0, x1};
          kept += x1 - x0;
        }
      }
      goff[i + 1] = kept;
    }
  });
  goff[0] = 0;
  for (int64_t i = 0; i < CN; ++i) goff[i + 1] += goff[i];
  const int64_t M = goff[CN];

  // (2) Depth order of the binned Gaussians of every camera.
  std::vector<std::vector<int32_t>> order(C);
  parallel_dynamic(C, [&](int64_t c) {
    auto& ids = order[c];
    ids.reserve(N);
    for (int64_t n = 0; n < N; ++n)
      if (goff[c * N + n + 1] > goff[c * N + n]) ids.push_back(static_cast<int32_t>(n));
    sort_by_depth(ids, dp + c * N);
  });

  // (3) Chunks of every camera's depth order: tile counts and each chunk's tile list.
  const int64_t K = threads;  // chunks per camera
  const int64_t units = C * K;
  std::vector<int64_t> counts(units * T, 0);  // per unit and tile; becomes the unit's cursors
  std::vector<std::vector<int32_t>> unit_tiles(units);
  auto unit_range = [&](int64_t u, int64_t& b, int64_t& e) {
    const int64_t n = static_cast<int64_t>(order[u / K].size()), k = u % K;
    b = n * k / K;
    e = n * (k + 1) / K;
  };
  parallel_dynamic(units, [&](int64_t u) {
    const int64_t c = u / K;
    int64_t b, e;
    unit_range(u, b, e);
    int64_t* cnt = counts.data() + u * T;
    std::vector<int32_t>& tl = unit_tiles[u];
    tl.reserve((goff[c * N + N] - goff[c * N]) * 5 / (4 * K) + 64);  // the camera's share, grows if needed
    const int32_t* ord = order[c].data();
    for (int64_t k = b; k < e; ++k) {
      // depth order is random in memory: fetch the records 16 and the row ranges 8 Gaussians ahead
      if (k + 16 < e) __builtin_prefetch(&bins[c * N + ord[k + 16]]);
      if (k + 8 < e) __builtin_prefetch(bins[c * N + ord[k + 8]].rows);
      const Binned& bn = bins[c * N + ord[k]];
      for (int y = bn.rect.y0; y < bn.rect.y1; ++y) {
        const Span& s = bn.rows[y - bn.rect.y0];
        for (int x = s.x0; x < s.x1; ++x) {
          const int32_t t = y * tiles_x + x;
          cnt[t]++;
          tl.push_back(t);
        }
      }
    }
  });
  torch::Tensor toff_t = torch::empty({C * T + 1}, lopt);
  int64_t* toff = toff_t.data_ptr<int64_t>();
  toff[0] = 0;
  for (int64_t c = 0; c < C; ++c)
    for (int64_t t = 0; t < T; ++t) {
      int64_t pos = toff[c * T + t];
      for (int64_t k = 0; k < K; ++k) {
        int64_t& cnt = counts[(c * K + k) * T + t];
        const int64_t n = cnt;
        cnt = pos;  // the unit's first slot in this tile
        pos += n;
      }
      toff[c * T + t + 1] = pos;
    }

  // (4) Scatter, in depth order within every chunk.
  torch::Tensor gid_t = torch::empty({M}, torch::TensorOptions().dtype(torch::kInt32));
  torch::Tensor gpos_t = torch::empty({M}, lopt);
  int32_t* gid = gid_t.data_ptr<int32_t>();
  int64_t* gpos = gpos_t.data_ptr<int64_t>();
  parallel_dynamic(units, [&](int64_t u) {
    const int64_t c = u / K;
    int64_t b, e;
    unit_range(u, b, e);
    int64_t* cursor = counts.data() + u * T;
    const int32_t* tl = unit_tiles[u].data();
    const int32_t* ord = order[c].data();
    for (int64_t k = b; k < e; ++k) {
      if (k + 16 < e) __builtin_prefetch(&goff[c * N + ord[k + 16]]);
      if (k + 8 < e) __builtin_prefetch(&gpos[goff[c * N + ord[k + 8]]], 1);
      const int32_t n = ord[k];
      const int64_t g0 = goff[c * N + n], g1 = goff[c * N + n + 1];
      for (int64_t j = g0; j < g1; ++j) {
        const int64_t pos = cursor[*tl++]++;
        gid[pos] = n;
        gpos[j] = pos;
      }
    }
  });
  return {params, toff_t, gid_t, goff_t, gpos_t};
}

// Forward compositing. Returns (feats [C,H,W,4], alpha [C,H,W,1], T_final [C,H,W], stop [C,H,W] i32).
// A pixel stops before the Gaussian that would bring its transmittance to <= t_stop (T_STOP when rendering;
// 0.5 for the median depth: the stopping Gaussian is the one where the ray's opacity crosses one half).
std::vector<torch::Tensor> rasterize_forward(torch::Tensor params, torch::Tensor tile_offsets,
                                             torch::Tensor isect_gid, int64_t C, int64_t N, int64_t width,
                                             int64_t height, double t_stop) {
  const float tstop = static_cast<float>(t_stop);
  const int tiles_x = static_cast<int>((width + TILE - 1) / TILE);
  const int tiles_y = static_cast<int>((height + TILE - 1) / TILE);
  const int64_t T = int64_t(tiles_x) * tiles_y;
  auto fopt = torch::TensorOptions().dtype(torch::kFloat32);
  // every pixel is written by its tile below
  torch::Tensor out = torch::empty({C, height, width, 4}, fopt);
  torch::Tensor alpha = torch::empty({C, height, width, 1}, fopt);
  torch::Tensor tfinal = torch::empty({C, height, width}, fopt);
  torch::Tensor stop = torch::empty({C, height, width}, torch::TensorOptions().dtype(torch::kInt32));
  const float* P = params.data_ptr<float>();
  const int64_t* toff = tile_offsets.data_ptr<int64_t>();
  const int32_t* gid = isect_gid.data_ptr<int32_t>();
  float* po = out.data_ptr<float>();
  float* pa = alpha.data_ptr<float>();
  float* pt = tfinal.data_ptr<float>();
  int32_t* ps = stop.data_ptr<int32_t>();

  parallel_dynamic(C * T, [&](int64_t tile) {
    const int64_t c = tile / T;
    const int tx = static_cast<int>((tile % T) % tiles_x), ty = static_cast<int>((tile % T) / tiles_x);
    const int x0 = tx * TILE, y0 = ty * TILE;
    const int64_t start = toff[tile];
    const int32_t L = static_cast<int32_t>(toff[tile + 1] - start);
    // Per tile row (16 lanes, updated by halves): transmittance, accumulated features and alpha, the index
    // of the Gaussian that stopped each pixel (L: none) and whether the pixel is still compositing.
    vf Tr[TILE], A0[TILE], A1[TILE], A2[TILE], A3[TILE], AW[TILE];
    vi ST[TILE], ACT[TILE];
    bool row_alive[TILE];
    int alive = 0;
    const vi in_cols = (LANE + float(x0)) < float(width);
    for (int r = 0; r < TILE; ++r) {
      row_alive[r] = (y0 + r) < height;
      alive += row_alive[r];
      Tr[r] = splat(1.0f);
      A0[r] = A1[r] = A2[r] = A3[r] = AW[r] = vf{};
      ST[r] = splati(L);
      ACT[r] = row_alive[r] ? in_cols : vi{};
    }
    const float* base = P + c * N * NP;
    for (int32_t i = 0; i < L && alive > 0; ++i) {
      const float* g = base + int64_t(gid[start + i]) * NP;
      // the parameters of the Gaussian two places on: depth order is random in memory (L2 misses beyond ~10k
      // Gaussians); prefetching them saves 5-10% of the forward and backward
      if (i + 2 < L) __builtin_prefetch(base + int64_t(gid[start + i + 2]) * NP);
      if (g[10] < 0.0f) continue;
      const float my = g[1], ca = g[2], cb = g[3], cc = g[4], o = g[5];
      const float f0 = g[6], f1 = g[7], f2 = g[8], f3 = g[9];
      const float dx0 = g[0] - (x0 + 0.5f);
      [[maybe_unused]] const vf dx = dx0 - LANE, dx2 = dx * dx;
      const HalfRowDx hdx(dx0);
      // Composites this Gaussian into pixels k .. k+lanes-1 of row r (16 lanes: the whole row; 8: one half).
      auto span = [&](auto dxv, auto dx2v, int r, int k, float cdy2, float bdy) {
        using V = decltype(dxv);
        using VI = decltype(dxv < dxv);
        const V sigma = 0.5f * (ca * dx2v + cdy2) + bdy * dxv;
        const V al = vmin(V{} + ALPHA_MAX, o * vexp_neg(-sigma));
        float* tr = lane_ptr(Tr[r], k);
        int32_t* act = lane_ptr(ACT[r], k);
        const VI use = (sigma >= 0.0f) & (al >= ALPHA_MIN) & ld<VI>(act);
        const V t = ld<V>(tr);
        const V nt = t * (1.0f - al);
        const VI halt = use & (nt <= tstop);
        const VI contrib = use & ~halt;
        const V w = contrib ? al * t : V{};
        float* a0 = lane_ptr(A0[r], k);
        float* a1 = lane_ptr(A1[r], k);
        float* a2 = lane_ptr(A2[r], k);
        float* a3 = lane_ptr(A3[r], k);
        float* aw = lane_ptr(AW[r], k);
        int32_t* sp = lane_ptr(ST[r], k);
        st(a0, ld<V>(a0) + w * f0);
        st(a1, ld<V>(a1) + w * f1);
        st(a2, ld<V>(a2) + w * f2);
        st(a3, ld<V>(a3) + w * f3);
        st(aw, ld<V>(aw) + w);  // alpha as the sum of weights: no cancellation in 1 - T
        st(tr, contrib ? nt : t);
        st(sp, halt ? VI{} + i : ld<VI>(sp));
        st(act, ld<VI>(act) & ~halt);
      };
      alignas(64) int32_t hit[TILE];
      rows_may_hit(g, float(x0), float(y0), hit);
      for (int r = 0; r < TILE; ++r) {
        const int halves = row_alive[r] ? hit[r] : 0;
        if (!halves) continue;
        const float dy = my - (y0 + r + 0.5f);
        const float cdy2 = cc * dy * dy, bdy = cb * dy;
#ifdef __AVX512F__
        if (halves == 3) {  // one zmm step for the whole row
          span(dx, dx2, r, 0, cdy2, bdy);
          continue;
        }
#endif
        // without AVX-512 a 16-lane step is lowered to slow code (2.8x the forward time on a 24k-Gaussian
        // 512 px model, AVX2): every row goes as 8-lane halves, with the same per-lane arithmetic
        if (halves & 1) span(hdx.dx[0], hdx.dx2[0], r, 0, cdy2, bdy);
        if (halves & 2) span(hdx.dx[1], hdx.dx2[1], r, HALF, cdy2, bdy);
      }
      if ((i & 7) == 7)  // retire finished rows (lazily: a finished row computes nothing anyway)
        for (int r = 0; r < TILE; ++r)
          if (row_alive[r] && !vany(ACT[r])) {
            row_alive[r] = false;
            --alive;
          }
    }
    for (int r = 0; r < TILE && y0 + r < height; ++r)
      for (int k = 0; k < TILE && x0 + k < width; ++k) {
        const int64_t pix = (c * height + y0 + r) * width + x0 + k;
        po[4 * pix] = A0[r][k];
        po[4 * pix + 1] = A1[r][k];
        po[4 * pix + 2] = A2[r][k];
        po[4 * pix + 3] = A3[r][k];
        pa[pix] = AW[r][k];
        pt[pix] = Tr[r][k];
        ps[pix] = ST[r][k];
      }
  });
  return {out, alpha, tfinal, stop};
}

// Backward. Returns (grad_means2d [C,N,2], grad_conics [C,N,3], grad_colors [C,N,3], grad_feat4 [C,N],
// grad_opacities [C,N]).
std::vector<torch::Tensor> rasterize_backward(torch::Tensor params, torch::Tensor tile_offsets,
                                              torch::Tensor isect_gid, torch::Tensor gauss_offsets,
                                              torch::Tensor gauss_isects, torch::Tensor tfinal,
                                              torch::Tensor stop, torch::Tensor grad_feats,
                                              torch::Tensor grad_alpha, int64_t C, int64_t N, int64_t width,
                                              int64_t height) {
  const int tiles_x = static_cast<int>((width + TILE - 1) / TILE);
  const int tiles_y = static_cast<int>((height + TILE - 1) / TILE);
  const int64_t T = int64_t(tiles_x) * tiles_y;
  const int64_t M = isect_gid.numel();
  auto fopt = torch::TensorOptions().dtype(torch::kFloat32);
  torch::Tensor rows = torch::empty({M, NG}, fopt);
  const float* P = params.data_ptr<float>();
  const int64_t* toff = tile_offsets.data_ptr<int64_t>();
  const int32_t* gid = isect_gid.data_ptr<int32_t>();
  const float* pt = tfinal.data_ptr<float>();
  const int32_t* ps = stop.data_ptr<int32_t>();
  const float* gf = grad_feats.data_ptr<float>();
  const float* ga = grad_alpha.data_ptr<float>();
  float* R = rows.data_ptr<float>();

  parallel_dynamic(C * T, [&](int64_t tile) {
    const int64_t c = tile / T;
    const int tx = static_cast<int>((tile % T) % tiles_x), ty = static_cast<int>((tile % T) / tiles_x);
    const int x0 = tx * TILE, y0 = ty * TILE;
    const int64_t start = toff[tile];
    const int32_t L = static_cast<int32_t>(toff[tile + 1] - start);
    if (L == 0) return;
    std::memset(R + start * NG, 0, sizeof(float) * NG * L);
    // Per tile row: Tr = transmittance after the current Gaussian (starts at the saved final one);
    // Q = Σ_ch G_ch S_ch - G_alpha T_final with S_ch = Σ_{later j} f_j,ch α_j T_j, so that
    // dL/dα_i = T_i (G·f_i) - Q / (1 - α_i)   (one accumulator instead of one per channel).
    vf Tr[TILE], Q[TILE], G0[TILE], G1[TILE], G2[TILE], G3[TILE];
    vi ST[TILE];
    int row_max[TILE][2];  // per half row: the largest stop index
    int imax = 0;
    for (int r = 0; r < TILE; ++r) {
      row_max[r][0] = row_max[r][1] = 0;
      for (int k = 0; k < TILE; ++k) {
        const bool inside = (y0 + r < height) && (x0 + k < width);
        const int64_t pix = inside ? (c * height + y0 + r) * width + x0 + k : 0;
        ST[r][k] = inside ? ps[pix] : 0;
        Tr[r][k] = inside ? pt[pix] : 1.0f;
        Q[r][k] = inside ? -ga[pix] * pt[pix] : 0.0f;
        G0[r][k] = inside ? gf[4 * pix] : 0.0f;
        G1[r][k] = inside ? gf[4 * pix + 1] : 0.0f;
        G2[r][k] = inside ? gf[4 * pix + 2] : 0.0f;
        G3[r][k] = inside ? gf[4 * pix + 3] : 0.0f;
        row_max[r][k / HALF] = std::max(row_max[r][k / HALF], ST[r][k]);
      }
      imax = std::max({imax, row_max[r][0], row_max[r][1]});
    }
    const float* base = P + c * N * NP;
    for (int32_t i = std::min(imax, L) - 1; i >= 0; --i) {
      const float* g = base + int64_t(gid[start + i]) * NP;
      if (i > 1) __builtin_prefetch(base + int64_t(gid[start + i - 2]) * NP);  // see the forward
      if (g[10] < 0.0f) continue;
      const float my = g[1], ca = g[2], cb = g[3], cc = g[4], o = g[5];
      const float f0 = g[6], f1 = g[7], f2 = g[8], f3 = g[9];
      const float dx0 = g[0] - (x0 + 0.5f);
      const HalfRowDx hdx(dx0);
      const vih iv = vih{} + i;
      // per-lane gradient sums of this pair, in half rows: mx my a b c o f0..f3
      vh sum[NG][2] = {};
      alignas(64) int32_t hit[TILE];
      rows_may_hit(g, float(x0), float(y0), hit);
      bool touched = false;
      // One half row (8 pixels) of row r; the other half is out of the Gaussian's reach or already stopped.
      auto half_row = [&](int r, int h, float dy, float cdy2, float bdy) {
        const int k = HALF * h;
        const vh dx = hdx.dx[h], dx2 = hdx.dx2[h];
        const vh sigma = 0.5f * (ca * dx2 + cdy2) + bdy * dx;
        const vh vis = vexp_neg(-sigma);
        const vh al_raw = o * vis;
        const vh al = vmin(vh{} + ALPHA_MAX, al_raw);
        const vih use = (sigma >= 0.0f) & (al >= ALPHA_MIN) & (iv < ld<vih>(lane_ptr(ST[r], k)));
        float* tr = lane_ptr(Tr[r], k);
        float* q = lane_ptr(Q[r], k);
        const vh g0 = ld<vh>(lane_ptr(G0[r], k)), g1 = ld<vh>(lane_ptr(G1[r], k));
        const vh g2 = ld<vh>(lane_ptr(G2[r], k)), g3 = ld<vh>(lane_ptr(G3[r], k));
        const vh ra = 1.0f / (1.0f - al);
        const vh t_old = ld<vh>(tr);
        const vh ti = t_old * ra;
        const vh w = use ? al * ti : vh{};
        const vh gfi = g0 * f0 + g1 * f1 + g2 * f2 + g3 * f3;
        const vh qv = ld<vh>(q);
        const vh d_al = use ? gfi * ti - qv * ra : vh{};
        st(q, qv + w * gfi);
        st(tr, use ? ti : t_old);
        sum[6][h] += w * g0;
        sum[7][h] += w * g1;
        sum[8][h] += w * g2;
        sum[9][h] += w * g3;
        const vih free_ = al_raw <= ALPHA_MAX;  // alpha not clamped: it depends on o and sigma
        const vh d_sig = free_ ? -d_al * al_raw : vh{};
        sum[5][h] += free_ ? d_al * vis : vh{};
        sum[0][h] += d_sig * (ca * dx + bdy);
        sum[1][h] += d_sig * (cb * dx + cc * dy);
        sum[2][h] += 0.5f * d_sig * dx2;
        sum[3][h] += d_sig * dx * dy;
        sum[4][h] += 0.5f * d_sig * (dy * dy);
      };
      for (int r = 0; r < TILE; ++r) {
        const int halves = hit[r] & ((i < row_max[r][0]) | ((i < row_max[r][1]) << 1));
        if (!halves) continue;
        touched = true;
        const float dy = my - (y0 + r + 0.5f);
        const float cdy2 = cc * dy * dy, bdy = cb * dy;
        if (halves & 1) half_row(r, 0, dy, cdy2, bdy);
        if (halves & 2) half_row(r, 1, dy, cdy2, bdy);
      }
      if (!touched) continue;  // its row stays zero (memset above)
      hsum_rows(sum, R + (start + i) * NG);
    }
  });

  // every Gaussian is written by the reduction below
  torch::Tensor g_m = torch::empty({C, N, 2}, fopt);
  torch::Tensor g_c = torch::empty({C, N, 3}, fopt);
  torch::Tensor g_col = torch::empty({C, N, 3}, fopt);
  torch::Tensor g_f4 = torch::empty({C, N}, fopt);
  torch::Tensor g_o = torch::empty({C, N}, fopt);
  float *pm = g_m.data_ptr<float>(), *pc = g_c.data_ptr<float>(), *pf = g_col.data_ptr<float>();
  float* pf4 = g_f4.data_ptr<float>();
  float* po = g_o.data_ptr<float>();
  const int64_t* goff = gauss_offsets.data_ptr<int64_t>();
  const int64_t* gpos = gauss_isects.data_ptr<int64_t>();
  // Ordered reduction: each Gaussian sums its tile rows in tile order (deterministic).
  at::parallel_for(0, C * N, 1024, [&](int64_t b, int64_t e) {
    for (int64_t n = b; n < e; ++n) {
      float acc[NG] = {0};
      for (int64_t j = goff[n]; j < goff[n + 1]; ++j) {
        const float* row = R + gpos[j] * NG;
        for (int q = 0; q < NG; ++q) acc[q] += row[q];
      }
      pm[2 * n] = acc[0];
      pm[2 * n + 1] = acc[1];
      pc[3 * n] = acc[2];
      pc[3 * n + 1] = acc[3];
      pc[3 * n + 2] = acc[4];
      po[n] = acc[5];
      for (int q = 0; q < 3; ++q) pf[3 * n + q] = acc[6 + q];
      pf4[n] = acc[9];
    }
  });
  return {g_m, g_c, g_col, g_f4, g_o};
}

// Splits the composited features into the render's outputs: rgb over a background (rgb + (1 - alpha) bg;
// bg [C,3] or empty for none), the expected depth acc_d / max(alpha, eps) and a copy of alpha (so that one
// autograd node owns all three). One pass instead of ~6 torch ops each way. Returns (rgb [C,H,W,3],
// depth [C,H,W,1], alpha [C,H,W,1]).
std::vector<torch::Tensor> finish_forward(torch::Tensor feats, torch::Tensor alpha, torch::Tensor bg, double eps) {
  const int64_t C = feats.size(0), HW = feats.size(1) * feats.size(2);
  auto fopt = torch::TensorOptions().dtype(torch::kFloat32);
  torch::Tensor rgb = torch::empty({C, feats.size(1), feats.size(2), 3}, fopt);
  torch::Tensor depth = torch::empty({C, feats.size(1), feats.size(2), 1}, fopt);
  torch::Tensor alpha_out = torch::empty_like(alpha);
  const float *pf = feats.data_ptr<float>(), *pa = alpha.data_ptr<float>();
  const float* pb = bg.numel() ? bg.data_ptr<float>() : nullptr;
  float *pr = rgb.data_ptr<float>(), *pd = depth.data_ptr<float>(), *po = alpha_out.data_ptr<float>();
  const float feps = static_cast<float>(eps);
  at::parallel_for(0, C * HW, 1 << 16, [&](int64_t b, int64_t e) {
    for (int64_t i = b; i < e; ++i) {
      const float a = pa[i], t = 1.0f - a;
      const float* f = pf + 4 * i;
      const float* bgc = pb ? pb + 3 * (i / HW) : nullptr;
      for (int k = 0; k < 3; ++k) pr[3 * i + k] = bgc ? f[k] + t * bgc[k] : f[k];
      pd[i] = f[3] / std::max(a, feps);
      po[i] = a;
    }
  });
  return {rgb, depth, alpha_out};
}

// Backward of finish_forward: (grad_feats [C,H,W,4], grad_alpha [C,H,W,1]); an empty grad_depth or
// grad_alpha counts as zero.
std::vector<torch::Tensor> finish_backward(torch::Tensor feats, torch::Tensor alpha, torch::Tensor bg, double eps,
                                           torch::Tensor g_rgb, torch::Tensor g_depth, torch::Tensor g_alpha) {
  const int64_t C = feats.size(0), HW = feats.size(1) * feats.size(2);
  torch::Tensor g_feats = torch::empty_like(feats);
  torch::Tensor g_a = torch::empty_like(alpha);
  const float *pf = feats.data_ptr<float>(), *pa = alpha.data_ptr<float>();
  const float* pb = bg.numel() ? bg.data_ptr<float>() : nullptr;
  const float* gr = g_rgb.data_ptr<float>();
  const float* gd = g_depth.numel() ? g_depth.data_ptr<float>() : nullptr;
  const float* ga = g_alpha.numel() ? g_alpha.data_ptr<float>() : nullptr;
  float *pgf = g_feats.data_ptr<float>(), *pga = g_a.data_ptr<float>();
  const float feps = static_cast<float>(eps);
  at::parallel_for(0, C * HW, 1 << 16, [&](int64_t b, int64_t e) {
    for (int64_t i = b; i < e; ++i) {
      const float a = pa[i];
      const float* g = gr + 3 * i;
      float ga_i = ga ? ga[i] : 0.0f;
      if (pb) {
        const float* bgc = pb + 3 * (i / HW);
        ga_i -= g[0] * bgc[0] + g[1] * bgc[1] + g[2] * bgc[2];
      }
      for (int k = 0; k < 3; ++k) pgf[4 * i + k] = g[k];
      const float den = std::max(a, feps), gdi = gd ? gd[i] : 0.0f;
      pgf[4 * i + 3] = gdi / den;
      if (gd && a >= feps) ga_i -= gdi * pf[4 * i + 3] / (den * den);
      pga[i] = ga_i;
    }
  });
  return {g_feats, g_a};
}

// project.cpp
std::vector<torch::Tensor> project_forward(torch::Tensor means, torch::Tensor quats, torch::Tensor scales,
                                           torch::Tensor opacities, torch::Tensor colors, torch::Tensor viewmats,
                                           torch::Tensor Ks, int64_t width, int64_t height, double near,
                                           double far, double eps2d, bool antialiased, int64_t sh_degree);
std::vector<torch::Tensor> project_backward(torch::Tensor means, torch::Tensor quats, torch::Tensor scales,
                                            torch::Tensor opacities, torch::Tensor colors, torch::Tensor viewmats,
                                            torch::Tensor Ks, int64_t width, int64_t height, double near,
                                            double far, double eps2d, bool antialiased, int64_t sh_degree,
                                            torch::Tensor g_means2d, torch::Tensor g_conics, torch::Tensor g_colors,
                                            torch::Tensor g_opac, torch::Tensor g_depths,
                                            bool pose_grad);

// adam.cpp
void adam_step(std::vector<torch::Tensor> params, std::vector<torch::Tensor> grads,
               std::vector<torch::Tensor> exp_avgs, std::vector<torch::Tensor> exp_avg_sqs,
               std::vector<double> lrs, std::vector<double> steps, double beta1, double beta2, double eps);

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.doc() = "go-pipeline CPU Gaussian rasterizer";
  m.def("bin_and_pack", &bin_and_pack, "tile binning and parameter packing");
  m.def("rasterize_forward", &rasterize_forward, "forward compositing");
  m.def("rasterize_backward", &rasterize_backward, "backward of the compositing");
  m.def("finish_forward", &finish_forward, "rgb over the background, expected depth");
  m.def("finish_backward", &finish_backward, "backward of finish_forward");
  m.def("project_forward", &project_forward, "EWA projection and SH colours");
  m.def("project_backward", &project_backward, "backward of the projection");
  m.def("adam_step", &adam_step, "one Adam step over several tensors in one parallel region");
}
