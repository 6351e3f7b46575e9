// EWA projection of 3D Gaussians and SH colour evaluation for C cameras, with a hand-written backward.
//
// Mirrors go_core/render/projection.py (the autograd version used by the reference backend) operation by
// operation, evaluating every Gaussian-camera pair in double precision. Eight consecutive Gaussians go
// through the maths together, one per lane of an 8-double vector (the last block repeats its last Gaussian
// in the unused lanes and stores nothing from them); every branch of the scalar maths is a per-lane select,
// written so that each lane computes exactly what the scalar formula would. The backward runs per Gaussian
// over the cameras in order and reduces the per-camera pose gradients over fixed blocks of Gaussians, so
// results do not depend on the thread count.

#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "simd.h"

namespace {

using go_simd::vd;
using go_simd::vl;
typedef float vf8 __attribute__((vector_size(32)));

constexpr int L = 8;  // Gaussians per vector
constexpr double SH_C0 = 0.28209479177387814;
constexpr double SH_C1 = 0.4886025119029199;
constexpr double SH_C2[5] = {1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
                             0.5462742152960396};
constexpr double SH_C3[7] = {-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
                             -0.4570457994644658, 1.445305721320277, -0.5900435899266435};
constexpr double MAX_AXIS_PX = 1e8;
constexpr double NORM_EPS = 1e-12;
constexpr int64_t BLOCK = 2048;  // Gaussians per block of the pose-gradient reduction
constexpr int MAX_COEFFS = 16 * 3;

// Lane-wise equivalents of the scalar functions (same results, NaN handling included).
inline vd splat(double x) { return vd{} + x; }
inline vd vmax(vd a, vd b) { return a < b ? b : a; }  // std::max(a, b)
inline vd vmin(vd a, vd b) { return b < a ? b : a; }  // std::min(a, b)
inline vd vmax(vd a, double b) { return vmax(a, splat(b)); }
inline vd vsqrt(vd x) {
  vd r;
  for (int k = 0; k < L; ++k) r[k] = std::sqrt(x[k]);
  return r;
}
inline vd vceil(vd x) {
  vd r;
  for (int k = 0; k < L; ++k) r[k] = std::ceil(x[k]);
  return r;
}
inline vl vfinite(vd x) { return (x - x) == 0.0; }  // false for inf and NaN
inline vl vabs_le(vd x, double lim) { return (x <= lim) & (x >= -lim); }  // |x| <= lim, false for NaN
inline vd vsel(vl m, vd a, vd b) { return m ? a : b; }

// The Gaussians of one vector: lane l holds Gaussian first + l, or the block's last one past its end.
// Rows move between memory and vectors through a small transposition buffer: a lane-by-lane gather or
// scatter of strided rows cost more than the maths (a third of the backward in a profile).
struct Lanes {
  int64_t idx[L];
  int count;
  Lanes(int64_t first, int64_t N) : count(static_cast<int>(std::min<int64_t>(L, N - first))) {
    for (int l = 0; l < L; ++l) idx[l] = first + std::min(l, count - 1);
  }
  // out[j] = the first nj fields of rows idx[0..7] of a row-major [*, S] array, in double.
  void load(const float* base, int64_t S, int nj, vd* out) const {
    alignas(64) vf8 tmp[MAX_COEFFS];
    for (int l = 0; l < L; ++l) {
      const float* row = base + S * idx[l];
      for (int j = 0; j < nj; ++j) tmp[j][l] = row[j];
    }
    for (int j = 0; j < nj; ++j) out[j] = __builtin_convertvector(tmp[j], vd);
  }
  vd load1(const float* base) const {
    vd v;
    load(base, 1, 1, &v);
    return v;
  }
  // Field j < nj of rows idx[0..count-1] of a row-major [*, S] array = v[j], converted to T.
  template <class T>
  void store(T* base, int64_t S, int nj, const vd* v) const {
    alignas(64) T tmp[MAX_COEFFS][L];
    for (int j = 0; j < nj; ++j)
      for (int l = 0; l < L; ++l) tmp[j][l] = static_cast<T>(v[j][l]);
    for (int l = 0; l < count; ++l) {
      T* row = base + S * idx[l];
      for (int j = 0; j < nj; ++j) row[j] = tmp[j][l];
    }
  }
};

// Basis values Y[0..15] and, when dY is given, their derivatives w.r.t. the unit direction (x, y, z).
void sh_basis(int deg, vd x, vd y, vd z, vd* Y, vd (*dY)[3]) {
  const vd zero = splat(0.0);
  Y[0] = splat(SH_C0);
  if (dY) dY[0][0] = dY[0][1] = dY[0][2] = zero;
  if (deg < 1) return;
  Y[1] = -SH_C1 * y;
  Y[2] = SH_C1 * z;
  Y[3] = -SH_C1 * x;
  if (dY) {
    for (int k = 1; k < 4; ++k) dY[k][0] = dY[k][1] = dY[k][2] = zero;
    dY[1][1] = splat(-SH_C1);
    dY[2][2] = splat(SH_C1);
    dY[3][0] = splat(-SH_C1);
  }
  if (deg < 2) return;
  const vd xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
  Y[4] = SH_C2[0] * xy;
  Y[5] = SH_C2[1] * yz;
  Y[6] = SH_C2[2] * (2.0 * zz - xx - yy);
  Y[7] = SH_C2[3] * xz;
  Y[8] = SH_C2[4] * (xx - yy);
  if (dY) {
    const vd d[5][3] = {{SH_C2[0] * y, SH_C2[0] * x, zero},
                        {zero, SH_C2[1] * z, SH_C2[1] * y},
                        {-2 * SH_C2[2] * x, -2 * SH_C2[2] * y, 4 * SH_C2[2] * z},
                        {SH_C2[3] * z, zero, SH_C2[3] * x},
                        {2 * SH_C2[4] * x, -2 * SH_C2[4] * y, zero}};
    for (int k = 0; k < 5; ++k)
      for (int j = 0; j < 3; ++j) dY[4 + k][j] = d[k][j];
  }
  if (deg < 3) return;
  Y[9] = SH_C3[0] * y * (3.0 * xx - yy);
  Y[10] = SH_C3[1] * xy * z;
  Y[11] = SH_C3[2] * y * (4.0 * zz - xx - yy);
  Y[12] = SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
  Y[13] = SH_C3[4] * x * (4.0 * zz - xx - yy);
  Y[14] = SH_C3[5] * z * (xx - yy);
  Y[15] = SH_C3[6] * x * (xx - 3.0 * yy);
  if (dY) {
    const vd d[7][3] = {
        {6 * SH_C3[0] * xy, SH_C3[0] * (3.0 * xx - 3.0 * yy), zero},
        {SH_C3[1] * yz, SH_C3[1] * xz, SH_C3[1] * xy},
        {-2 * SH_C3[2] * xy, SH_C3[2] * (4.0 * zz - xx - 3.0 * yy), 8 * SH_C3[2] * yz},
        {-6 * SH_C3[3] * xz, -6 * SH_C3[3] * yz, SH_C3[3] * (6.0 * zz - 3.0 * xx - 3.0 * yy)},
        {SH_C3[4] * (4.0 * zz - 3.0 * xx - yy), -2 * SH_C3[4] * xy, 8 * SH_C3[4] * xz},
        {2 * SH_C3[5] * xz, -2 * SH_C3[5] * yz, SH_C3[5] * (xx - yy)},
        {SH_C3[6] * (3.0 * xx - 3.0 * yy), -6 * SH_C3[6] * xy, zero}};
    for (int k = 0; k < 7; ++k)
      for (int j = 0; j < 3; ++j) dY[9 + k][j] = d[k][j];
  }
}

struct Cam {
  double R[3][3], t[3], fx, fy, cx, cy, campos[3];
  double lo_x, hi_x, lo_y, hi_y;  // x/z and y/z limits of the Jacobian: 1.3x the field of view
};

Cam load_cam(const float* vm, const float* K, int64_t width, int64_t height) {
  Cam c;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) c.R[i][j] = vm[4 * i + j];
    c.t[i] = vm[4 * i + 3];
  }
  c.fx = K[0];
  c.fy = K[4];
  c.cx = K[2];
  c.cy = K[5];
  for (int i = 0; i < 3; ++i) c.campos[i] = -(c.R[0][i] * c.t[0] + c.R[1][i] * c.t[1] + c.R[2][i] * c.t[2]);
  const double W = double(width), H = double(height);
  const double tfx = 0.5 * W / c.fx, tfy = 0.5 * H / c.fy;
  c.hi_x = (W - c.cx) / c.fx + 0.3 * tfx;
  c.lo_x = -(c.cx / c.fx + 0.3 * tfx);
  c.hi_y = (H - c.cy) / c.fy + 0.3 * tfy;
  c.lo_y = -(c.cy / c.fy + 0.3 * tfy);
  return c;
}

struct Settings {
  int64_t width, height;
  double near, far, eps2d;
  bool antialiased;
  int sh_degree;  // -1: colours are RGB
};

// The per-Gaussian inputs of one vector, in double.
struct Inputs {
  vd m[3], s[3], q[4], opac;
  vd coef[MAX_COEFFS];  // SH coefficients (k, channel) or RGB
  Inputs(const Lanes& ln, const float* pm, const float* pq, const float* ps, const float* po, const float* pc,
         int64_t K, int ncoef) {
    ln.load(pm, 3, 3, m);
    ln.load(ps, 3, 3, s);
    ln.load(pq, 4, 4, q);
    opac = ln.load1(po);
    ln.load(pc, K * 3, ncoef, coef);
  }
};

// The quaternion's rotation, shared by all cameras.
struct Rot {
  vd Rq[3][3], qn[4], qnorm;
  explicit Rot(const vd* q) {
    const vd n = vsqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    qnorm = n;
    const vd inv = 1.0 / vmax(n, NORM_EPS);
    const vd w = q[0] * inv, x = q[1] * inv, y = q[2] * inv, z = q[3] * inv;
    qn[0] = w, qn[1] = x, qn[2] = y, qn[3] = z;
    Rq[0][0] = 1 - 2 * (y * y + z * z);
    Rq[0][1] = 2 * (x * y - w * z);
    Rq[0][2] = 2 * (x * z + w * y);
    Rq[1][0] = 2 * (x * y + w * z);
    Rq[1][1] = 1 - 2 * (x * x + z * z);
    Rq[1][2] = 2 * (y * z - w * x);
    Rq[2][0] = 2 * (x * z - w * y);
    Rq[2][1] = 2 * (y * z + w * x);
    Rq[2][2] = 1 - 2 * (x * x + y * y);
  }
};

// Everything the forward computes for one vector of Gaussians in one camera (kept for the backward).
struct Geo {
  vd p[3], rz, xr, yr, tx, ty;
  vd J00, J02, J11, J12;  // J01 = J10 = 0
  vd WM[3][3], M[3][3], T[2][3];
  vd a_raw, b, c_raw, det_raw, a, c, det;
  vl in_depth, valid_T;

  Geo(const Inputs& in, const Rot& rot, const Cam& cam, const Settings& st) {
    const vd* m = in.m;
    for (int i = 0; i < 3; ++i) p[i] = cam.R[i][0] * m[0] + cam.R[i][1] * m[1] + cam.R[i][2] * m[2] + cam.t[i];
    const vl finite = vfinite(p[0]) & vfinite(p[1]) & vfinite(p[2]);
    in_depth = finite & (p[2] >= st.near) & (p[2] <= st.far);
    const vd x = vsel(in_depth, p[0], splat(0.0)), y = vsel(in_depth, p[1], splat(0.0));
    const vd z = vsel(in_depth, p[2], splat(1.0));
    rz = 1.0 / z;
    xr = x * rz;
    yr = y * rz;
    tx = z * vmin(splat(cam.hi_x), vmax(splat(cam.lo_x), xr));
    ty = z * vmin(splat(cam.hi_y), vmax(splat(cam.lo_y), yr));
    J00 = cam.fx * rz;
    J02 = -cam.fx * tx * rz * rz;
    J11 = cam.fy * rz;
    J12 = -cam.fy * ty * rz * rz;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) M[i][j] = rot.Rq[i][j] * in.s[j];
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) WM[i][j] = cam.R[i][0] * M[0][j] + cam.R[i][1] * M[1][j] + cam.R[i][2] * M[2][j];
    vl ok = vl{} - 1;
    for (int j = 0; j < 3; ++j) {  // J @ WM with the zero entries kept, as the reference (NaN and inf included)
      T[0][j] = J00 * WM[0][j] + 0.0 * WM[1][j] + J02 * WM[2][j];
      T[1][j] = 0.0 * WM[0][j] + J11 * WM[1][j] + J12 * WM[2][j];
      ok = ok & vabs_le(T[0][j], MAX_AXIS_PX) & vabs_le(T[1][j], MAX_AXIS_PX);
    }
    valid_T = in_depth & ok;
    for (int i = 0; i < 2; ++i)
      for (int j = 0; j < 3; ++j) T[i][j] = vsel(valid_T, T[i][j], splat(0.0));
    const vd* t0 = T[0];
    const vd* t1 = T[1];
    a_raw = t0[0] * t0[0] + t0[1] * t0[1] + t0[2] * t0[2];
    b = t0[0] * t1[0] + t0[1] * t1[1] + t0[2] * t1[2];
    c_raw = t1[0] * t1[0] + t1[1] * t1[1] + t1[2] * t1[2];
    const vd m01 = t0[0] * t1[1] - t0[1] * t1[0];
    const vd m02 = t0[0] * t1[2] - t0[2] * t1[0];
    const vd m12 = t0[1] * t1[2] - t0[2] * t1[1];
    det_raw = m01 * m01 + m02 * m02 + m12 * m12;
    a = a_raw + st.eps2d;
    c = c_raw + st.eps2d;
    det = det_raw + st.eps2d * (a_raw + c_raw) + st.eps2d * st.eps2d;
  }
};

// Unit view directions (camera centre to Gaussian) with their length, for the SH colours.
struct ViewDir {
  vd dn[3], len, inv;
  ViewDir(const vd* m, const Cam& cam) {
    const vd d[3] = {m[0] - cam.campos[0], m[1] - cam.campos[1], m[2] - cam.campos[2]};
    len = vsqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    inv = 1.0 / vmax(len, NORM_EPS);
    for (int j = 0; j < 3; ++j) dn[j] = d[j] * inv;
  }
};

// Σ_k Y[k] coef[k, ch] + 0.5 (before the clamp at 0).
inline vd sh_colour(const vd* Y, const vd* coef, int nb, int ch) {
  vd acc = splat(0.0);
  for (int k = 0; k < nb; ++k) acc += Y[k] * coef[3 * k + ch];
  return acc + 0.5;
}

int64_t num_vectors(int64_t N) { return (N + L - 1) / L; }

}  // namespace

// Forward: (means2d [C,N,2], conics [C,N,3], colors [C,N,3], opacities [C,N], depths [C,N], radii [C,N] i32)
std::vector<torch::Tensor> project_forward(torch::Tensor means, torch::Tensor quats, torch::Tensor scales,
                                           torch::Tensor opacities, torch::Tensor colors, torch::Tensor viewmats,
                                           torch::Tensor Ks, int64_t width, int64_t height, double near,
                                           double far, double eps2d, bool antialiased, int64_t sh_degree) {
  const int64_t N = means.size(0), C = viewmats.size(0);
  const int64_t K = sh_degree >= 0 ? colors.size(1) : 1;
  const int nb = sh_degree >= 0 ? static_cast<int>((sh_degree + 1) * (sh_degree + 1)) : 1;
  const Settings st{width, height, near, far, eps2d, antialiased, static_cast<int>(sh_degree)};
  auto fopt = torch::TensorOptions().dtype(torch::kFloat32);
  torch::Tensor m2 = torch::empty({C, N, 2}, fopt), con = torch::empty({C, N, 3}, fopt);
  torch::Tensor col = torch::empty({C, N, 3}, fopt), op = torch::empty({C, N}, fopt);
  torch::Tensor dep = torch::empty({C, N}, fopt);
  torch::Tensor rad = torch::empty({C, N}, torch::TensorOptions().dtype(torch::kInt32));
  const float *pm = means.data_ptr<float>(), *pq = quats.data_ptr<float>(), *ps = scales.data_ptr<float>();
  const float *po = opacities.data_ptr<float>(), *pc = colors.data_ptr<float>();
  const float *pv = viewmats.data_ptr<float>(), *pk = Ks.data_ptr<float>();
  float *om = m2.data_ptr<float>(), *oc = con.data_ptr<float>(), *ocol = col.data_ptr<float>();
  float *oo = op.data_ptr<float>(), *od = dep.data_ptr<float>();
  int32_t* orad = rad.data_ptr<int32_t>();
  std::vector<Cam> cams(C);
  for (int64_t c = 0; c < C; ++c) cams[c] = load_cam(pv + 16 * c, pk + 9 * c, width, height);

  at::parallel_for(0, num_vectors(N), 64, [&](int64_t v0, int64_t v1) {
    vd Y[16];
    for (int64_t v = v0; v < v1; ++v) {
      const Lanes ln(v * L, N);
      const Inputs in(ln, pm, pq, ps, po, pc, K, 3 * nb);
      const Rot rot(in.q);
      for (int64_t c = 0; c < C; ++c) {
        const Cam& cam = cams[c];
        const Geo g(in, rot, cam, st);
        const int64_t off = c * N;
        const vd u = cam.fx * vsel(g.in_depth, g.p[0], splat(0.0)) * g.rz + cam.cx;
        const vd vv = cam.fy * vsel(g.in_depth, g.p[1], splat(0.0)) * g.rz + cam.cy;
        const vd uv[2] = {u, vv}, conic[3] = {g.c / g.det, -g.b / g.det, g.a / g.det};
        const vd depth = vsel(g.in_depth, g.p[2], splat(1.0));
        ln.store(om + 2 * off, 2, 2, uv);
        ln.store(oc + 3 * off, 3, 3, conic);
        ln.store(od + off, 1, 1, &depth);
        const vd mid = 0.5 * (g.a + g.c), hd = 0.5 * (g.a - g.c);
        const vd lam = mid + vsqrt(vmax(hd * hd + g.b * g.b, 0.01));
        const vd r = vceil(3.0 * vsqrt(lam));
        const vl on_screen = (u + r > 0) & (u - r < double(width)) & (vv + r > 0) & (vv - r < double(height));
        const vl keep = g.valid_T & on_screen;
        for (int l = 0; l < ln.count; ++l) orad[off + ln.idx[l]] = keep[l] ? static_cast<int32_t>(r[l]) : 0;
        vd o = in.opac;
        if (antialiased) o *= vsqrt(vmax(g.det_raw / g.det, 1e-12));
        ln.store(oo + off, 1, 1, &o);
        if (sh_degree >= 0) {
          const ViewDir vdir(in.m, cam);
          sh_basis(static_cast<int>(sh_degree), vdir.dn[0], vdir.dn[1], vdir.dn[2], Y, nullptr);
          vd rgb[3];
          for (int ch = 0; ch < 3; ++ch) rgb[ch] = vmax(sh_colour(Y, in.coef, nb, ch), 0.0);
          ln.store(ocol + 3 * off, 3, 3, rgb);
        } else {
          ln.store(ocol + 3 * off, 3, 3, in.coef);
        }
      }
    }
  });
  return {m2, con, col, op, dep, rad};
}

// Backward: (d means [N,3], d quats [N,4], d scales [N,3], d opacities [N], d colors (like colors),
//            d viewmats [C,4,4]; zeros unless pose_grad).
std::vector<torch::Tensor> project_backward(torch::Tensor means, torch::Tensor quats, torch::Tensor scales,
                                            torch::Tensor opacities, torch::Tensor colors, torch::Tensor viewmats,
                                            torch::Tensor Ks, int64_t width, int64_t height, double near,
                                            double far, double eps2d, bool antialiased, int64_t sh_degree,
                                            torch::Tensor g_means2d, torch::Tensor g_conics, torch::Tensor g_colors,
                                            torch::Tensor g_opac, torch::Tensor g_depths,
                                            bool pose_grad) {
  const int64_t N = means.size(0), C = viewmats.size(0);
  const int64_t K = sh_degree >= 0 ? colors.size(1) : 1;
  const int nb = sh_degree >= 0 ? static_cast<int>((sh_degree + 1) * (sh_degree + 1)) : 1;
  const Settings st{width, height, near, far, eps2d, antialiased, static_cast<int>(sh_degree)};
  auto fopt = torch::TensorOptions().dtype(torch::kFloat32);
  // every Gaussian (and every camera-Gaussian pose row) is written below
  torch::Tensor dm = torch::empty({N, 3}, fopt), dq = torch::empty({N, 4}, fopt), ds = torch::empty({N, 3}, fopt);
  torch::Tensor dop = torch::empty({N}, fopt), dcol = torch::empty_like(colors);
  torch::Tensor pose_rows = torch::empty({pose_grad ? C : 0, N, 12}, torch::TensorOptions().dtype(torch::kFloat64));
  const float *pm = means.data_ptr<float>(), *pq = quats.data_ptr<float>(), *ps = scales.data_ptr<float>();
  const float *po = opacities.data_ptr<float>(), *pc = colors.data_ptr<float>();
  const float *pv = viewmats.data_ptr<float>(), *pk = Ks.data_ptr<float>();
  const float *gm2 = g_means2d.data_ptr<float>(), *gcon = g_conics.data_ptr<float>();
  const float *gcol = g_colors.data_ptr<float>(), *gop = g_opac.data_ptr<float>(), *gdep = g_depths.data_ptr<float>();
  float *odm = dm.data_ptr<float>(), *odq = dq.data_ptr<float>(), *ods = ds.data_ptr<float>();
  float *odo = dop.data_ptr<float>(), *odc = dcol.data_ptr<float>();
  double* rows = pose_rows.data_ptr<double>();
  std::vector<Cam> cams(C);
  for (int64_t c = 0; c < C; ++c) cams[c] = load_cam(pv + 16 * c, pk + 9 * c, width, height);
  const double eps = eps2d;
  const vd zero = splat(0.0);

  at::parallel_for(0, num_vectors(N), 64, [&](int64_t v0, int64_t v1) {
    vd Y[16], dY[16][3], dco[MAX_COEFFS];
    for (int64_t v = v0; v < v1; ++v) {
      const Lanes ln(v * L, N);
      const Inputs in(ln, pm, pq, ps, po, pc, K, 3 * nb);
      const Rot rot(in.q);
      vd dmean[3] = {zero, zero, zero}, dqn[4] = {zero, zero, zero, zero}, dsc[3] = {zero, zero, zero};
      vd dopac = zero;
      for (int k = 0; k < 3 * nb; ++k) dco[k] = zero;
      for (int64_t c = 0; c < C; ++c) {
        const Cam& cam = cams[c];
        const int64_t off = c * N;
        const Geo g(in, rot, cam, st);
        vd dR[3][3], dt[3];  // pose gradient of this camera (only with pose_grad)
        for (int a = 0; a < 3; ++a) {
          dt[a] = zero;
          for (int b = 0; b < 3; ++b) dR[a][b] = zero;
        }

        // colours
        if (sh_degree >= 0) {
          const ViewDir vdir(in.m, cam);
          const vd* dn = vdir.dn;
          sh_basis(static_cast<int>(sh_degree), dn[0], dn[1], dn[2], Y, dY);
          vd gc[3];
          ln.load(gcol + 3 * off, 3, 3, gc);
          for (int ch = 0; ch < 3; ++ch) gc[ch] = vsel(sh_colour(Y, in.coef, nb, ch) >= 0.0, gc[ch], zero);
          vd ddn[3] = {zero, zero, zero};
          for (int k = 0; k < nb; ++k) {
            const vd* co = in.coef + 3 * k;
            const vd dyk = co[0] * gc[0] + co[1] * gc[1] + co[2] * gc[2];
            for (int ch = 0; ch < 3; ++ch) dco[3 * k + ch] += Y[k] * gc[ch];
            for (int j = 0; j < 3; ++j) ddn[j] += dyk * dY[k][j];
          }
          const vd proj = dn[0] * ddn[0] + dn[1] * ddn[1] + dn[2] * ddn[2];
          const vl long_dir = vdir.len > NORM_EPS;
          vd dd[3];
          for (int j = 0; j < 3; ++j) dd[j] = vsel(long_dir, (ddn[j] - dn[j] * proj) * vdir.inv, ddn[j] * vdir.inv);
          for (int j = 0; j < 3; ++j) dmean[j] += dd[j];
          // campos_i = -Σ_j R_ji t_j, d campos = -dd
          if (pose_grad)
            for (int a = 0; a < 3; ++a)
              for (int b = 0; b < 3; ++b) {
                dR[b][a] += cam.t[b] * dd[a];
                dt[b] += cam.R[b][a] * dd[a];
              }
        } else {
          vd gc[3];
          ln.load(gcol + 3 * off, 3, 3, gc);
          for (int ch = 0; ch < 3; ++ch) dco[ch] += gc[ch];
        }

        // opacity (with the antialiasing compensation)
        vd ddet_raw = zero, ddet = zero;
        const vd go = ln.load1(gop + off);
        if (antialiased) {
          const vd ratio = g.det_raw / g.det;
          const vd comp = vsqrt(vmax(ratio, 1e-12));
          dopac += go * comp;
          const vl kept = ratio >= 1e-12;
          const vd dratio = go * in.opac * 0.5 / comp;
          ddet_raw = vsel(kept, ddet_raw + dratio / g.det, ddet_raw);
          ddet = vsel(kept, ddet + -dratio * g.det_raw / (g.det * g.det), ddet);
        } else {
          dopac += go;
        }

        // means2d and depth (lanes in front of the camera)
        const vd x = g.p[0], y = g.p[1], z = g.p[2], rz = g.rz;
        vd guv[2];
        ln.load(gm2 + 2 * off, 2, 2, guv);
        const vd gu = guv[0], gv = guv[1];
        vd dp[3] = {gu * cam.fx * rz, gv * cam.fy * rz, ln.load1(gdep + off)};
        vd drz = gu * cam.fx * x + gv * cam.fy * y;

        {  // covariance (lanes with a valid projection)
          const vl vt = g.valid_T;
          // conic = (c, -b, a) / det
          vd gq[3];
          ln.load(gcon + 3 * off, 3, 3, gq);
          const vd g0 = gq[0], g1 = gq[1], g2 = gq[2];
          const vd da = g2 / g.det, dc = g0 / g.det, db = -g1 / g.det;
          const vd ddet_c = ddet + -(g0 * g.c - g1 * g.b + g2 * g.a) / (g.det * g.det);
          const vd ddet_raw_c = ddet_raw + ddet_c;
          const vd da_raw = da + eps * ddet_c, dc_raw = dc + eps * ddet_c;
          const vd* t0 = g.T[0];
          const vd* t1 = g.T[1];
          vd dT[2][3];
          for (int j = 0; j < 3; ++j) {
            dT[0][j] = 2.0 * da_raw * t0[j] + db * t1[j];
            dT[1][j] = 2.0 * dc_raw * t1[j] + db * t0[j];
          }
          const vd m01 = t0[0] * t1[1] - t0[1] * t1[0];
          const vd m02 = t0[0] * t1[2] - t0[2] * t1[0];
          const vd m12 = t0[1] * t1[2] - t0[2] * t1[1];
          const vd d01 = 2.0 * m01 * ddet_raw_c, d02 = 2.0 * m02 * ddet_raw_c, d12 = 2.0 * m12 * ddet_raw_c;
          dT[0][0] += d01 * t1[1] + d02 * t1[2];
          dT[1][1] += d01 * t0[0] - d12 * t0[2];
          dT[0][1] += -d01 * t1[0] + d12 * t1[2];
          dT[1][0] += -d01 * t0[1] - d02 * t0[2];
          dT[1][2] += d02 * t0[0] + d12 * t0[1];
          dT[0][2] += -d02 * t1[0] - d12 * t1[1];
          // T = J WM
          const vd J[2][3] = {{g.J00, zero, g.J02}, {zero, g.J11, g.J12}};
          vd dJ[2][3], dWM[3][3];
          for (int a = 0; a < 2; ++a)
            for (int b = 0; b < 3; ++b)
              dJ[a][b] = dT[a][0] * g.WM[b][0] + dT[a][1] * g.WM[b][1] + dT[a][2] * g.WM[b][2];
          for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) dWM[a][b] = J[0][a] * dT[0][b] + J[1][a] * dT[1][b];
          // WM = R M
          vd dM[3][3];
          for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) {
              if (pose_grad)
                dR[a][b] = vsel(vt, dR[a][b] + (dWM[a][0] * g.M[b][0] + dWM[a][1] * g.M[b][1] + dWM[a][2] * g.M[b][2]),
                                dR[a][b]);
              dM[a][b] = cam.R[0][a] * dWM[0][b] + cam.R[1][a] * dWM[1][b] + cam.R[2][a] * dWM[2][b];
            }
          // M = Rq diag(s)
          vd dRq[3][3];
          for (int b = 0; b < 3; ++b) {
            vd acc = dsc[b];
            for (int a = 0; a < 3; ++a) {
              dRq[a][b] = dM[a][b] * in.s[b];
              acc += dM[a][b] * rot.Rq[a][b];
            }
            dsc[b] = vsel(vt, acc, dsc[b]);
          }
          const vd w = rot.qn[0], qx = rot.qn[1], qy = rot.qn[2], qz = rot.qn[3];
          const vd dq0 = dqn[0] + 2 * (-qz * dRq[0][1] + qy * dRq[0][2] + qz * dRq[1][0] - qx * dRq[1][2] -
                                       qy * dRq[2][0] + qx * dRq[2][1]);
          const vd dq1 = dqn[1] + 2 * (qy * dRq[0][1] + qz * dRq[0][2] + qy * dRq[1][0] - 2 * qx * dRq[1][1] -
                                       w * dRq[1][2] + qz * dRq[2][0] + w * dRq[2][1] - 2 * qx * dRq[2][2]);
          const vd dq2 = dqn[2] + 2 * (-2 * qy * dRq[0][0] + qx * dRq[0][1] + w * dRq[0][2] + qx * dRq[1][0] +
                                       qz * dRq[1][2] - w * dRq[2][0] + qz * dRq[2][1] - 2 * qy * dRq[2][2]);
          const vd dq3 = dqn[3] + 2 * (-2 * qz * dRq[0][0] - w * dRq[0][1] + qx * dRq[0][2] + w * dRq[1][0] -
                                       2 * qz * dRq[1][1] + qy * dRq[1][2] + qx * dRq[2][0] + qy * dRq[2][1]);
          dqn[0] = vsel(vt, dq0, dqn[0]);
          dqn[1] = vsel(vt, dq1, dqn[1]);
          dqn[2] = vsel(vt, dq2, dqn[2]);
          dqn[3] = vsel(vt, dq3, dqn[3]);
          // J(x, y, z): J00 = fx rz, J02 = -fx tx rz², J11 = fy rz, J12 = -fy ty rz²
          vd drz_c = drz + (cam.fx * dJ[0][0] + cam.fy * dJ[1][1]);
          const vd dtx = -cam.fx * rz * rz * dJ[0][2], dty = -cam.fy * rz * rz * dJ[1][2];
          drz_c += -2.0 * cam.fx * g.tx * rz * dJ[0][2] - 2.0 * cam.fy * g.ty * rz * dJ[1][2];
          // tx = z * clamp(x rz): the clamp passes the gradient only strictly inside its limits
          const vd cxr = vmin(splat(cam.hi_x), vmax(splat(cam.lo_x), g.xr));
          const vd cyr = vmin(splat(cam.hi_y), vmax(splat(cam.lo_y), g.yr));
          const vd dp2_c = dp[2] + (cxr * dtx + cyr * dty);
          const vl inside_x = (g.xr > cam.lo_x) & (g.xr < cam.hi_x);
          const vl inside_y = (g.yr > cam.lo_y) & (g.yr < cam.hi_y);
          const vd dp0_c = vsel(inside_x, dp[0] + z * dtx * rz, dp[0]);
          drz_c = vsel(inside_x, drz_c + z * dtx * x, drz_c);
          const vd dp1_c = vsel(inside_y, dp[1] + z * dty * rz, dp[1]);
          drz_c = vsel(inside_y, drz_c + z * dty * y, drz_c);
          dp[0] = vsel(vt, dp0_c, dp[0]);
          dp[1] = vsel(vt, dp1_c, dp[1]);
          dp[2] = vsel(vt, dp2_c, dp[2]);
          drz = vsel(vt, drz_c, drz);
        }
        dp[2] += -rz * rz * drz;
        // p = R m + t
        const vl id = g.in_depth;
        for (int a = 0; a < 3; ++a) {
          dmean[a] = vsel(id, dmean[a] + (cam.R[0][a] * dp[0] + cam.R[1][a] * dp[1] + cam.R[2][a] * dp[2]), dmean[a]);
          if (pose_grad) {
            for (int b = 0; b < 3; ++b) dR[a][b] = vsel(id, dR[a][b] + dp[a] * in.m[b], dR[a][b]);
            dt[a] = vsel(id, dt[a] + dp[a], dt[a]);
          }
        }
        if (pose_grad) {
          const vd row[12] = {dR[0][0], dR[0][1], dR[0][2], dR[1][0], dR[1][1], dR[1][2],
                              dR[2][0], dR[2][1], dR[2][2], dt[0],    dt[1],    dt[2]};
          ln.store(rows + 12 * off, 12, 12, row);
        }
      }
      // normalisation of the quaternion: q / max(|q|, eps)
      const vd inv = 1.0 / vmax(rot.qnorm, NORM_EPS);
      const vd proj = rot.qn[0] * dqn[0] + rot.qn[1] * dqn[1] + rot.qn[2] * dqn[2] + rot.qn[3] * dqn[3];
      const vl normalised = rot.qnorm > NORM_EPS;
      vd dquat[4];
      for (int j = 0; j < 4; ++j) dquat[j] = vsel(normalised, (dqn[j] - rot.qn[j] * proj) * inv, dqn[j] * inv);
      ln.store(odq, 4, 4, dquat);
      ln.store(odm, 3, 3, dmean);
      ln.store(ods, 3, 3, dsc);
      ln.store(odo, 1, 1, &dopac);
      ln.store(odc, K * 3, 3 * nb, dco);
      if (sh_degree >= 0)
        for (int l = 0; l < ln.count; ++l)  // bands above the active degree
          std::fill(odc + ln.idx[l] * K * 3 + 3 * nb, odc + (ln.idx[l] + 1) * K * 3, 0.0f);
    }
  });

  torch::Tensor dvm = torch::zeros({C, 4, 4}, fopt);
  if (!pose_grad) return {dm, dq, ds, dop, dcol, dvm};
  // Pose gradient: fixed blocks of Gaussians, summed in block order (independent of the thread count).
  const int64_t nblocks = (N + BLOCK - 1) / BLOCK;
  std::vector<double> partial(C * std::max<int64_t>(nblocks, 1) * 12, 0.0);
  at::parallel_for(0, C * nblocks, 1, [&](int64_t u0, int64_t u1) {
    for (int64_t u = u0; u < u1; ++u) {
      const int64_t c = u / nblocks, blk = u % nblocks;
      double* acc = partial.data() + 12 * u;
      for (int64_t n = blk * BLOCK; n < std::min(N, (blk + 1) * BLOCK); ++n)
        for (int q = 0; q < 12; ++q) acc[q] += rows[12 * (c * N + n) + q];
    }
  });
  float* pdv = dvm.data_ptr<float>();
  for (int64_t c = 0; c < C; ++c) {
    double acc[12] = {0};
    for (int64_t blk = 0; blk < nblocks; ++blk)
      for (int q = 0; q < 12; ++q) acc[q] += partial[12 * (c * nblocks + blk) + q];
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) pdv[16 * c + 4 * a + b] = float(acc[3 * a + b]);
      pdv[16 * c + 4 * a + 3] = float(acc[9 + a]);
    }
  }
  return {dm, dq, ds, dop, dcol, dvm};
}
