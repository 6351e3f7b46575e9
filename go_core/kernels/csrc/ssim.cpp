// Mean SSIM of one image pair (the 3DGS training loss term) and its gradient w.r.t. the first image.
//
// Same definition as go_core/losses.py::ssim_map: separable Gaussian window g (passed in; 11 taps, sigma 1.5,
// fixed at compile time so the filter loops unroll), zero padding of 5, C1/C2 constants, mean over all pixels
// and channels. Images are float32 [H,W,C] contiguous (the renderer's layout; C = 1, 3 or 4), processed as
// H rows of L = W*C interleaved values, so the horizontal filter steps by C inside a row. All filtering and
// the per-pixel algebra run in double: the variances E[x^2] - mu^2 and the gradient's G*A + 2x G*B + y G*C
// cancel badly in float32 (torch's float32 path is off by up to ~4e-5 in value and ~4e-4 in gradient).
//
// Forward, per output row: vertical filter of x, y, x^2, y^2, xy straight from the input rows (products
// formed on the fly), then the horizontal filter, then SSIM and, if a gradient is wanted, the per-pixel
// partials A = df/dmu1, B = df/dE[x^2], C = df/dE[xy] (saved, [3,H,L] double; the loss is a scalar, so
// these are all the backward needs). Backward, per output row: G*A, G*B, G*C (the window is symmetric and
// zero padding makes the filter self-adjoint), combined as scale * (G*A + 2x G*B + y G*C). Rows are
// independent and the mean is reduced from per-row sums in row order, so results are bit-identical for any
// thread count. Exposed as torch.ops.go_ssim.{forward,backward} (the rasterizer owns the pybind module).
//
// go_ssim.{terms_forward,terms_backward} add, in the same pass over the rows, the other per-pixel terms of
// the coarse loss: mean |x - y| and the mean binary cross-entropy of an [H,W] alpha against an [H,W] mask
// (alpha clamped to [lo, hi], as go_core/losses.py::mask_bce). One parallel region each way instead of
// ~30 small torch ops (each of which must wake the OpenMP team, see go_pipeline/openmp.py).

#include <torch/extension.h>
#include <torch/library.h>
#include <ATen/Parallel.h>
#include <ATen/core/dispatch/Dispatcher.h>

#include <algorithm>
#include <cmath>
#include <array>
#include <cstdint>
#include <memory>
#include <type_traits>
#include <vector>

#include "simd.h"

namespace {

constexpr int R = 5;  // window radius: 11 taps, the 3DGS window (a compile-time constant so loops unroll)
constexpr int K = 2 * R + 1;

std::array<double, K> check_window(const torch::Tensor& window) {
  TORCH_CHECK(window.dim() == 1 && window.scalar_type() == torch::kFloat64 && window.device().is_cpu() &&
                  window.numel() == K,
              "ssim: window must be a float64 CPU tensor of ", K, " taps");
  auto w = window.contiguous();
  std::array<double, K> g;
  std::copy(w.data_ptr<double>(), w.data_ptr<double>() + K, g.begin());
  for (int k = 0; k < R; ++k) TORCH_CHECK(g[k] == g[K - 1 - k], "ssim: window must be symmetric");
  return g;
}

void check_image(const torch::Tensor& t, const char* name) {
  TORCH_CHECK(t.dim() == 3 && t.scalar_type() == torch::kFloat32 && t.device().is_cpu() && t.is_contiguous(),
              "ssim: ", name, " must be a contiguous float32 CPU tensor [H,W,C]");
}

// Optional per-row terms computed beside SSIM (see the header). Null pointers switch a term off.
struct Extras {
  double* l1_rows = nullptr;   // [H] sums of |x - y| over a row (forward)
  const float* alpha = nullptr;  // [H,W]
  const float* mask = nullptr;   // [H,W]
  float lo = 0.0f, hi = 1.0f;    // alpha clamp bounds
  double* bce_rows = nullptr;  // [H] BCE sums over a row (forward)
  double l1_scale = 0.0;       // backward: gradient of l1_scale * sum|x - y| added to grad x
  float* grad_alpha = nullptr;  // backward: [H,W] gradient of bce_scale * sum BCE
  double bce_scale = 0.0;
};

using go_simd::vany;
using go_simd::vf;
using go_simd::vi;

// log(x) for normal positive floats: Cephes logf (x = m 2^e, m in [sqrt(1/2), sqrt(2)), degree-8
// polynomial in m - 1; about 1 ulp). Lanes outside the normal range (0, denormals, inf, NaN) go to std::log.
inline vf vlogf(vf x) {
  vi bits = (vi)x;
  vi e = ((bits >> 23) & 0xff) - 126;  // x = m 2^e with m in [0.5, 1)
  vf m = (vf)((bits & 0x007fffff) | 0x3f000000);
  const vi low = m < 0.70710678118654752440f;
  e = low ? e - 1 : e;
  m = low ? m + m - 1.0f : m - 1.0f;
  const vf fe = __builtin_convertvector(e, vf);
  const vf z = m * m;
  vf y = m * 7.0376836292e-2f - 1.1514610310e-1f;
  y = y * m + 1.1676998740e-1f;
  y = y * m - 1.2420140846e-1f;
  y = y * m + 1.4249322787e-1f;
  y = y * m - 1.6668057665e-1f;
  y = y * m + 2.0000714765e-1f;
  y = y * m - 2.4999993993e-1f;
  y = y * m + 3.3333331174e-1f;
  y = y * m * z;
  y = y + fe * -2.12194440e-4f - 0.5f * z;
  vf r = (m + y) + fe * 0.693359375f;
  const vi odd = !((x >= 1.17549435e-38f) & (x <= 3.40282347e38f));
  if (vany(odd))
    for (int k = 0; k < 16; ++k)
      if (odd[k]) r[k] = std::log(x[k]);
  return r;
}

// Sum over one row of -(m log a + (1 - m) log(1 - a)) with a clamped to [lo, hi], as mask_bce: the two logs
// in float32, as torch evaluates mask_bce for a float32 alpha (log(1 - a) as log1p: log(u) (u - 1)^-1 (-a),
// u = 1 - a, exact where u rounds to 1), 16 pixels per vector; combined and summed in double, in a fixed order.
inline double bce_row(const float* alpha, const float* mask, int64_t W, float lo, float hi) {
  double sum = 0.0;
  for (int64_t w0 = 0; w0 < W; w0 += 16) {
    const int n = static_cast<int>(std::min<int64_t>(16, W - w0));
    vf raw, m;
    for (int k = 0; k < 16; ++k) {
      raw[k] = k < n ? alpha[w0 + k] : 0.5f;
      m[k] = k < n ? mask[w0 + k] : 0.0f;
    }
    vf a = raw > lo ? raw : lo;
    a = a < hi ? a : hi;
    a = raw == raw ? a : raw;  // a NaN alpha stays NaN, as with torch's clamp
    const vf u = 1.0f - a;
    const vf l0 = u == 1.0f ? -a : vlogf(u) / (u - 1.0f) * -a;
    const vf la = vlogf(a);
    // combined in double: where m = 1 and a ~ 1, l0 + (la - l0) would cancel badly in float
    for (int k = 0; k < n; ++k) sum -= double(l0[k]) + double(m[k]) * (double(la[k]) - double(l0[k]));
  }
  return sum;
}

// Its derivative w.r.t. alpha; zero where the clamp is active (torch's clamp passes the gradient on [lo, hi]).
inline double bce_grad(float alpha, float m, float lo, float hi) {
  if (!(alpha >= lo && alpha <= hi)) return 0.0;
  const double a = alpha;
  return -double(m) / a + (1.0 - double(m)) / (1.0 - a);
}

// Runs body(h0, h1, scratch) over blocks of rows [h0, h1), scheduled dynamically over at::get_num_threads()
// OpenMP threads (as the rasterizer does: a thread the OS deschedules on shared cores does not hold up the
// others). scratch: per-thread, `scratch_size` doubles, zero-initialised once. Small images run serially.
template <typename F>
void for_row_blocks(int64_t H, int64_t L, int64_t scratch_size, const F& body) {
  const int64_t rows = std::max<int64_t>(1, 8192 / std::max<int64_t>(L, 1));  // ~8k values per block
  const int64_t blocks = (H + rows - 1) / rows;
  const int64_t work = H * L;
  const int nt = work < 32768 ? 1 : static_cast<int>(std::min<int64_t>(at::get_num_threads(), blocks));
#pragma omp parallel num_threads(std::max(nt, 1))
  {
    std::vector<double> scratch(scratch_size, 0.0);
#pragma omp for schedule(dynamic, 1)
    for (int64_t b = 0; b < blocks; ++b) body(b * rows, std::min(H, (b + 1) * rows), scratch.data());
  }
}

// The K input rows around output row h (a zero row outside the image).
template <typename T>
std::array<const T*, K> window_rows(const T* base, const T* zeros, int64_t h, int64_t H, int64_t L) {
  std::array<const T*, K> rows;
  for (int k = 0; k < K; ++k) {
    const int64_t s = h + k - R;
    rows[k] = (s >= 0 && s < H) ? base + s * L : zeros;
  }
  return rows;
}

// Horizontal filter of a row zero-padded by R*C on both sides (p points at its first value).
template <int C>
inline void hfilter_row(const double* p, double* out, int64_t L, const std::array<double, K>& g) {
#pragma omp simd
  for (int64_t j = 0; j < L; ++j) {
    double s = g[R] * p[j];
    for (int k = 0; k < R; ++k) s += g[k] * (p[j - (R - k) * C] + p[j + (R - k) * C]);
    out[j] = s;
  }
}

// SSIM of the filtered moments at one pixel; with kGrad also the partials A, B, C (see the header).
template <bool kGrad>
inline double ssim_pixel(double m1, double m2, double e11, double e22, double e12, double c1, double c2,
                         double* A, double* B, double* Cc) {
  const double m11 = m1 * m1, m22 = m2 * m2, m12 = m1 * m2;
  const double n1 = 2.0 * m12 + c1, n2 = 2.0 * (e12 - m12) + c2;
  const double d1 = m11 + m22 + c1, d2 = (e11 - m11) + (e22 - m22) + c2;
  const double inv = 1.0 / (d1 * d2);
  const double f = n1 * n2 * inv;
  if constexpr (kGrad) {
    const double b = -f / d2;                                         // df/ds1 = df/dE[x^2]
    const double c = 2.0 * n1 * inv;                                  // df/ds12 = df/dE[xy]
    const double a_direct = 2.0 * m2 * n2 * inv - 2.0 * m1 * f / d1;  // df/dmu1 at fixed s1, s12
    *A = a_direct - 2.0 * m1 * b - m2 * c;  // s1 = E[x^2] - mu1^2, s12 = E[xy] - mu1 mu2
    *B = b;
    *Cc = c;
  }
  return f;
}

template <int C, bool kGrad>
double forward_impl(const float* x, const float* y, double* abc, int64_t H, int64_t W,
                    const std::array<double, K>& g, double c1, double c2, const Extras& ex = Extras()) {
  const int64_t L = W * C, P = R * C, HL = H * L;
  std::vector<double> row_sum(H);
  const std::vector<float> zeros(L, 0.0f);
  // scratch: the five vertically filtered rows, zero-padded by P for the horizontal pass, then the five
  // filtered moment rows
  for_row_blocks(H, L, 5 * (L + 2 * P) + 5 * L, [&](int64_t h0, int64_t h1, double* scratch) {
    double* v0 = scratch + P;
    double* v1 = v0 + (L + 2 * P);
    double* v2 = v1 + (L + 2 * P);
    double* v3 = v2 + (L + 2 * P);
    double* v4 = v3 + (L + 2 * P);
    double* f0 = scratch + 5 * (L + 2 * P);
    double *f1 = f0 + L, *f2 = f1 + L, *f3 = f2 + L, *f4 = f3 + L;
    for (int64_t h = h0; h < h1; ++h) {
      const auto xr = window_rows(x, zeros.data(), h, H, L);
      const auto yr = window_rows(y, zeros.data(), h, H, L);
#pragma omp simd
      for (int64_t j = 0; j < L; ++j) {
        const double a = xr[R][j], b = yr[R][j];
        double s0 = g[R] * a, s1 = g[R] * b, s2 = g[R] * (a * a), s3 = g[R] * (b * b), s4 = g[R] * (a * b);
        for (int k = 0; k < R; ++k) {
          const double a0 = xr[k][j], a1 = xr[K - 1 - k][j], b0 = yr[k][j], b1 = yr[K - 1 - k][j];
          s0 += g[k] * (a0 + a1);
          s1 += g[k] * (b0 + b1);
          s2 += g[k] * (a0 * a0 + a1 * a1);
          s3 += g[k] * (b0 * b0 + b1 * b1);
          s4 += g[k] * (a0 * b0 + a1 * b1);
        }
        v0[j] = s0;
        v1[j] = s1;
        v2[j] = s2;
        v3[j] = s3;
        v4[j] = s4;
      }
      hfilter_row<C>(v0, f0, L, g);
      hfilter_row<C>(v1, f1, L, g);
      hfilter_row<C>(v2, f2, L, g);
      hfilter_row<C>(v3, f3, L, g);
      hfilter_row<C>(v4, f4, L, g);
      double s = 0.0;
      if constexpr (kGrad) {
        double* A = abc + h * L;
        double* B = abc + HL + h * L;
        double* Cc = abc + 2 * HL + h * L;
#pragma omp simd reduction(+ : s)
        for (int64_t j = 0; j < L; ++j)
          s += ssim_pixel<true>(f0[j], f1[j], f2[j], f3[j], f4[j], c1, c2, A + j, B + j, Cc + j);
      } else {
#pragma omp simd reduction(+ : s)
        for (int64_t j = 0; j < L; ++j)
          s += ssim_pixel<false>(f0[j], f1[j], f2[j], f3[j], f4[j], c1, c2, nullptr, nullptr, nullptr);
      }
      row_sum[h] = s;
      if (ex.l1_rows) {
        const float *xh = x + h * L, *yh = y + h * L;
        double d = 0.0;
#pragma omp simd reduction(+ : d)
        for (int64_t j = 0; j < L; ++j) d += std::fabs(double(xh[j]) - double(yh[j]));
        ex.l1_rows[h] = d;
      }
      if (ex.bce_rows) {
        const float *ah = ex.alpha + h * W, *mh = ex.mask + h * W;
        ex.bce_rows[h] = bce_row(ah, mh, W, ex.lo, ex.hi);
      }
    }
  });
  double total = 0.0;
  for (int64_t h = 0; h < H; ++h) total += row_sum[h];
  return total;
}

template <int C>
void backward_impl(const float* x, const float* y, const double* abc, float* grad, int64_t H, int64_t W,
                   const std::array<double, K>& g, double scale, const Extras& ex = Extras()) {
  const int64_t L = W * C, P = R * C, HL = H * L;
  const std::vector<double> zeros(L, 0.0);
  for_row_blocks(H, L, 3 * (L + 2 * P) + 3 * L, [&](int64_t h0, int64_t h1, double* scratch) {
    double* v[3] = {scratch + P, scratch + P + (L + 2 * P), scratch + P + 2 * (L + 2 * P)};
    double* f[3] = {scratch + 3 * (L + 2 * P), scratch + 3 * (L + 2 * P) + L, scratch + 3 * (L + 2 * P) + 2 * L};
    for (int64_t h = h0; h < h1; ++h) {
      for (int q = 0; q < 3; ++q) {
        const auto rows = window_rows(abc + q * HL, zeros.data(), h, H, L);
        double* vq = v[q];
#pragma omp simd
        for (int64_t j = 0; j < L; ++j) {
          double sq = g[R] * rows[R][j];
          for (int k = 0; k < R; ++k) sq += g[k] * (rows[k][j] + rows[K - 1 - k][j]);
          vq[j] = sq;
        }
      }
      const float* xh = x + h * L;
      const float* yh = y + h * L;
      float* gh = grad + h * L;
      hfilter_row<C>(v[0], f[0], L, g);
      hfilter_row<C>(v[1], f[1], L, g);
      hfilter_row<C>(v[2], f[2], L, g);
      const double *ga = f[0], *gb = f[1], *gc = f[2];
      const double l1s = ex.l1_scale;
#pragma omp simd
      for (int64_t j = 0; j < L; ++j) {
        const double sgn = double((xh[j] > yh[j]) - (xh[j] < yh[j]));
        gh[j] = static_cast<float>(scale * (ga[j] + 2.0 * double(xh[j]) * gb[j] + double(yh[j]) * gc[j]) +
                                   l1s * sgn);
      }
      if (ex.grad_alpha) {
        const float *ah = ex.alpha + h * W, *mh = ex.mask + h * W;
        float* gah = ex.grad_alpha + h * W;
        for (int64_t w = 0; w < W; ++w)
          gah[w] = static_cast<float>(ex.bce_scale * bce_grad(ah[w], mh[w], ex.lo, ex.hi));
      }
    }
  });
}

// Calls f(std::integral_constant<int, C>) for the supported channel counts.
template <typename F>
void dispatch_channels(int64_t c, F&& f) {
  switch (c) {
    case 1: return f(std::integral_constant<int, 1>{});
    case 3: return f(std::integral_constant<int, 3>{});
    case 4: return f(std::integral_constant<int, 4>{});
    default: TORCH_CHECK(false, "ssim: 1, 3 or 4 channels supported, got ", c);
  }
}

void check_alpha_mask(const torch::Tensor& x, const torch::Tensor& alpha, const torch::Tensor& mask) {
  for (const auto* t : {&alpha, &mask})
    TORCH_CHECK(t->dim() == 2 && t->scalar_type() == torch::kFloat32 && t->device().is_cpu() &&
                    t->is_contiguous() && t->size(0) == x.size(0) && t->size(1) == x.size(1),
                "ssim terms: alpha and mask must be contiguous float32 CPU tensors [H,W] of the image's size");
}

// SSIM, L1 and (when alpha has elements) BCE(alpha, mask) of one pair in one pass. Returns (mean SSIM,
// mean |x - y|, mean BCE (0 without alpha), all float64 scalars; SSIM partials [3,H,W*C] or empty).
std::vector<torch::Tensor> terms_forward(const torch::Tensor& x, const torch::Tensor& y,
                                         const torch::Tensor& window, double c1, double c2,
                                         const torch::Tensor& alpha, const torch::Tensor& mask, double lo,
                                         double hi, bool need_grad) {
  check_image(x, "x");
  check_image(y, "y");
  TORCH_CHECK(x.sizes() == y.sizes(), "ssim: image shapes differ");
  TORCH_CHECK(x.numel() > 0, "ssim: empty image");
  const bool bce = alpha.numel() > 0;
  if (bce) check_alpha_mask(x, alpha, mask);
  const auto g = check_window(window);
  const int64_t H = x.size(0), W = x.size(1);
  auto dopt = torch::TensorOptions().dtype(torch::kFloat64);
  torch::Tensor abc = need_grad ? torch::empty({3, H, W * x.size(2)}, dopt) : torch::empty({0}, dopt);
  std::vector<double> l1_rows(H), bce_rows(bce ? H : 0);
  Extras ex;
  ex.l1_rows = l1_rows.data();
  if (bce) {
    ex.alpha = alpha.data_ptr<float>();
    ex.mask = mask.data_ptr<float>();
    ex.lo = static_cast<float>(lo);
    ex.hi = static_cast<float>(hi);
    ex.bce_rows = bce_rows.data();
  }
  double total = 0.0;
  dispatch_channels(x.size(2), [&](auto cc) {
    constexpr int C = decltype(cc)::value;
    const float *xp = x.data_ptr<float>(), *yp = y.data_ptr<float>();
    total = need_grad ? forward_impl<C, true>(xp, yp, abc.data_ptr<double>(), H, W, g, c1, c2, ex)
                      : forward_impl<C, false>(xp, yp, nullptr, H, W, g, c1, c2, ex);
  });
  double l1 = 0.0, b = 0.0;
  for (int64_t h = 0; h < H; ++h) l1 += l1_rows[h];
  for (double v : bce_rows) b += v;
  const double n = double(x.numel());
  return {torch::scalar_tensor(total / n, dopt), torch::scalar_tensor(l1 / n, dopt),
          torch::scalar_tensor(bce ? b / double(H * W) : 0.0, dopt), abc};
}

// Gradients of ssim_scale * sum(SSIM map) + l1_scale * sum|x - y| w.r.t. x [H,W,C], and of
// bce_scale * sum BCE(alpha, mask) w.r.t. alpha [H,W] (an empty tensor without alpha).
std::vector<torch::Tensor> terms_backward(const torch::Tensor& x, const torch::Tensor& y,
                                          const torch::Tensor& abc, const torch::Tensor& window,
                                          double ssim_scale, double l1_scale, const torch::Tensor& alpha,
                                          const torch::Tensor& mask, double lo, double hi, double bce_scale) {
  check_image(x, "x");
  check_image(y, "y");
  const auto g = check_window(window);
  TORCH_CHECK(y.sizes() == x.sizes() && abc.scalar_type() == torch::kFloat64 && abc.is_contiguous() &&
                  abc.numel() == 3 * x.numel(),
              "ssim: partials must be contiguous float64 [3,H,W*C]");
  const bool bce = alpha.numel() > 0;
  if (bce) check_alpha_mask(x, alpha, mask);
  auto fopt = torch::TensorOptions().dtype(torch::kFloat32);
  torch::Tensor grad = torch::empty(x.sizes(), fopt);
  torch::Tensor grad_alpha = bce ? torch::empty(alpha.sizes(), fopt) : torch::empty({0}, fopt);
  Extras ex;
  ex.l1_scale = l1_scale;
  if (bce) {
    ex.alpha = alpha.data_ptr<float>();
    ex.mask = mask.data_ptr<float>();
    ex.lo = static_cast<float>(lo);
    ex.hi = static_cast<float>(hi);
    ex.grad_alpha = grad_alpha.data_ptr<float>();
    ex.bce_scale = bce_scale;
  }
  dispatch_channels(x.size(2), [&](auto cc) {
    backward_impl<decltype(cc)::value>(x.data_ptr<float>(), y.data_ptr<float>(), abc.data_ptr<double>(),
                                       grad.data_ptr<float>(), x.size(0), x.size(1), g, ssim_scale, ex);
  });
  return {grad, grad_alpha};
}

// Returns (mean SSIM as a float64 scalar, partials [3,H,W*C] float64 or an empty tensor).
std::vector<torch::Tensor> ssim_forward(const torch::Tensor& x, const torch::Tensor& y,
                                        const torch::Tensor& window, double c1, double c2, bool need_grad) {
  const torch::Tensor none = torch::empty({0}, torch::TensorOptions().dtype(torch::kFloat32));
  auto t = terms_forward(x, y, window, c1, c2, none, none, 0.0, 1.0, need_grad);
  return {t[0], t[3]};
}

// Gradient [H,W,C] float32 of scale * sum(SSIM map) w.r.t. x, from the saved partials.
torch::Tensor ssim_backward(const torch::Tensor& x, const torch::Tensor& y, const torch::Tensor& abc,
                            const torch::Tensor& window, double scale) {
  const torch::Tensor none = torch::empty({0}, torch::TensorOptions().dtype(torch::kFloat32));
  return terms_backward(x, y, abc, window, scale, 0.0, none, none, 0.0, 1.0, 0.0)[0];
}

// Registered once per process even if a second copy of this library is loaded (same ops, same code).
struct Registrar {
  std::unique_ptr<torch::Library> lib;
  Registrar() {
    if (c10::Dispatcher::singleton().findSchema({"go_ssim::forward", ""}).has_value()) return;
    lib = std::make_unique<torch::Library>(torch::Library::DEF, "go_ssim", std::nullopt, __FILE__, __LINE__);
    lib->def("forward(Tensor x, Tensor y, Tensor window, float c1, float c2, bool need_grad) -> Tensor[]",
             &ssim_forward);
    lib->def("backward(Tensor x, Tensor y, Tensor partials, Tensor window, float scale) -> Tensor",
             &ssim_backward);
    lib->def(
        "terms_forward(Tensor x, Tensor y, Tensor window, float c1, float c2, Tensor alpha, Tensor mask, "
        "float lo, float hi, bool need_grad) -> Tensor[]",
        &terms_forward);
    lib->def(
        "terms_backward(Tensor x, Tensor y, Tensor partials, Tensor window, float ssim_scale, float l1_scale, "
        "Tensor alpha, Tensor mask, float lo, float hi, float bce_scale) -> Tensor[]",
        &terms_backward);
  }
};
const Registrar registrar;

}  // namespace
