// EWA projection of 3D Gaussians and SH colour evaluation for C cameras, with a hand-written backward.
//
// Mirrors go_core/render/projection.py (the autograd version used by the reference backend) operation by
// operation, but evaluates every Gaussian-camera pair in double precision in one pass. The backward runs
// per Gaussian over the cameras in order and reduces the per-camera pose gradients over fixed blocks of
// Gaussians, so results do not depend on the thread count.

#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

namespace {

constexpr double SH_C0 = 0.28209479177387814;
constexpr double SH_C1 = 0.4886025119029199;
constexpr double SH_C2[5] = {1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
                             0.5462742152960396};
constexpr double SH_C3[7] = {-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
                             -0.4570457994644658, 1.445305721320277, -0.5900435899266435};
constexpr double MAX_AXIS_PX = 1e8;
constexpr double NORM_EPS = 1e-12;
constexpr int64_t BLOCK = 2048;  // Gaussians per block of the pose-gradient reduction

// Basis values Y[0..15] and, when dY is given, their derivatives w.r.t. the unit direction (x, y, z).
void sh_basis(int deg, double x, double y, double z, double* Y, double (*dY)[3]) {
  Y[0] = SH_C0;
  if (dY) dY[0][0] = dY[0][1] = dY[0][2] = 0.0;
  if (deg < 1) return;
  Y[1] = -SH_C1 * y;
  Y[2] = SH_C1 * z;
  Y[3] = -SH_C1 * x;
  if (dY) {
    const double d[3][3] = {{0, -SH_C1, 0}, {0, 0, SH_C1}, {-SH_C1, 0, 0}};
    for (int k = 0; k < 3; ++k)
      for (int j = 0; j < 3; ++j) dY[1 + k][j] = d[k][j];
  }
  if (deg < 2) return;
  const double xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
  Y[4] = SH_C2[0] * xy;
  Y[5] = SH_C2[1] * yz;
  Y[6] = SH_C2[2] * (2.0 * zz - xx - yy);
  Y[7] = SH_C2[3] * xz;
  Y[8] = SH_C2[4] * (xx - yy);
  if (dY) {
    const double d[5][3] = {{SH_C2[0] * y, SH_C2[0] * x, 0},
                            {0, SH_C2[1] * z, SH_C2[1] * y},
                            {-2 * SH_C2[2] * x, -2 * SH_C2[2] * y, 4 * SH_C2[2] * z},
                            {SH_C2[3] * z, 0, SH_C2[3] * x},
                            {2 * SH_C2[4] * x, -2 * SH_C2[4] * y, 0}};
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
    const double d[7][3] = {
        {6 * SH_C3[0] * xy, SH_C3[0] * (3 * xx - 3 * yy), 0},
        {SH_C3[1] * yz, SH_C3[1] * xz, SH_C3[1] * xy},
        {-2 * SH_C3[2] * xy, SH_C3[2] * (4 * zz - xx - 3 * yy), 8 * SH_C3[2] * yz},
        {-6 * SH_C3[3] * xz, -6 * SH_C3[3] * yz, SH_C3[3] * (6 * zz - 3 * xx - 3 * yy)},
        {SH_C3[4] * (4 * zz - 3 * xx - yy), -2 * SH_C3[4] * xy, 8 * SH_C3[4] * xz},
        {2 * SH_C3[5] * xz, -2 * SH_C3[5] * yz, SH_C3[5] * (xx - yy)},
        {SH_C3[6] * (3 * xx - 3 * yy), -6 * SH_C3[6] * xy, 0}};
    for (int k = 0; k < 7; ++k)
      for (int j = 0; j < 3; ++j) dY[9 + k][j] = d[k][j];
  }
}

struct Cam {
  double R[3][3], t[3], fx, fy, cx, cy, campos[3];
};

Cam load_cam(const float* vm, const float* K) {
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
  return c;
}

struct Settings {
  int64_t width, height;
  double near, far, eps2d;
  bool antialiased;
  int sh_degree;  // -1: colours are RGB
};

// Everything the forward computes for one Gaussian in one camera (kept for the backward's recomputation).
struct Geo {
  double p[3], rz, xr, yr, tx, ty, lo_x, hi_x, lo_y, hi_y;
  double J[2][3], WM[3][3], M[3][3], Rq[3][3], qn[4], qnorm;
  double T[2][3], a_raw, b, c_raw, det_raw, a, c, det;
  bool in_depth, valid_T;
};

void rotmat(const float* q, Geo& g) {
  const double n = std::sqrt(double(q[0]) * q[0] + double(q[1]) * q[1] + double(q[2]) * q[2] + double(q[3]) * q[3]);
  g.qnorm = n;
  const double inv = 1.0 / std::max(n, NORM_EPS);
  const double w = q[0] * inv, x = q[1] * inv, y = q[2] * inv, z = q[3] * inv;
  g.qn[0] = w, g.qn[1] = x, g.qn[2] = y, g.qn[3] = z;
  double(&R)[3][3] = g.Rq;
  R[0][0] = 1 - 2 * (y * y + z * z);
  R[0][1] = 2 * (x * y - w * z);
  R[0][2] = 2 * (x * z + w * y);
  R[1][0] = 2 * (x * y + w * z);
  R[1][1] = 1 - 2 * (x * x + z * z);
  R[1][2] = 2 * (y * z - w * x);
  R[2][0] = 2 * (x * z - w * y);
  R[2][1] = 2 * (y * z + w * x);
  R[2][2] = 1 - 2 * (x * x + y * y);
}

void geometry(const float* m, const float* s, const Cam& cam, const Settings& st, Geo& g) {
  for (int i = 0; i < 3; ++i)
    g.p[i] = cam.R[i][0] * m[0] + cam.R[i][1] * m[1] + cam.R[i][2] * m[2] + cam.t[i];
  const bool finite = std::isfinite(g.p[0]) && std::isfinite(g.p[1]) && std::isfinite(g.p[2]);
  g.in_depth = finite && g.p[2] >= st.near && g.p[2] <= st.far;
  const double x = g.in_depth ? g.p[0] : 0.0, y = g.in_depth ? g.p[1] : 0.0, z = g.in_depth ? g.p[2] : 1.0;
  g.rz = 1.0 / z;
  const double W = double(st.width), H = double(st.height);
  const double tfx = 0.5 * W / cam.fx, tfy = 0.5 * H / cam.fy;
  g.hi_x = (W - cam.cx) / cam.fx + 0.3 * tfx;
  g.lo_x = -(cam.cx / cam.fx + 0.3 * tfx);
  g.hi_y = (H - cam.cy) / cam.fy + 0.3 * tfy;
  g.lo_y = -(cam.cy / cam.fy + 0.3 * tfy);
  g.xr = x * g.rz;
  g.yr = y * g.rz;
  g.tx = z * std::min(g.hi_x, std::max(g.lo_x, g.xr));
  g.ty = z * std::min(g.hi_y, std::max(g.lo_y, g.yr));
  g.J[0][0] = cam.fx * g.rz;
  g.J[0][1] = 0.0;
  g.J[0][2] = -cam.fx * g.tx * g.rz * g.rz;
  g.J[1][0] = 0.0;
  g.J[1][1] = cam.fy * g.rz;
  g.J[1][2] = -cam.fy * g.ty * g.rz * g.rz;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) g.M[i][j] = g.Rq[i][j] * s[j];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      g.WM[i][j] = cam.R[i][0] * g.M[0][j] + cam.R[i][1] * g.M[1][j] + cam.R[i][2] * g.M[2][j];
  bool ok = true;
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 3; ++j) {
      g.T[i][j] = g.J[i][0] * g.WM[0][j] + g.J[i][1] * g.WM[1][j] + g.J[i][2] * g.WM[2][j];
      ok = ok && std::fabs(g.T[i][j]) <= MAX_AXIS_PX;  // false for NaN too
    }
  g.valid_T = g.in_depth && ok;
  if (!g.valid_T)
    for (int i = 0; i < 2; ++i)
      for (int j = 0; j < 3; ++j) g.T[i][j] = 0.0;
  const double* t0 = g.T[0];
  const double* t1 = g.T[1];
  g.a_raw = t0[0] * t0[0] + t0[1] * t0[1] + t0[2] * t0[2];
  g.b = t0[0] * t1[0] + t0[1] * t1[1] + t0[2] * t1[2];
  g.c_raw = t1[0] * t1[0] + t1[1] * t1[1] + t1[2] * t1[2];
  const double m01 = t0[0] * t1[1] - t0[1] * t1[0];
  const double m02 = t0[0] * t1[2] - t0[2] * t1[0];
  const double m12 = t0[1] * t1[2] - t0[2] * t1[1];
  g.det_raw = m01 * m01 + m02 * m02 + m12 * m12;
  g.a = g.a_raw + st.eps2d;
  g.c = g.c_raw + st.eps2d;
  g.det = g.det_raw + st.eps2d * (g.a_raw + g.c_raw) + st.eps2d * st.eps2d;
}

}  // namespace

// Forward: (means2d [C,N,2], conics [C,N,3], colors [C,N,3], opacities [C,N], depths [C,N], radii [C,N] i32)
std::vector<torch::Tensor> project_forward(torch::Tensor means, torch::Tensor quats, torch::Tensor scales,
                                           torch::Tensor opacities, torch::Tensor colors, torch::Tensor viewmats,
                                           torch::Tensor Ks, int64_t width, int64_t height, double near,
                                           double far, double eps2d, bool antialiased, int64_t sh_degree) {
  const int64_t N = means.size(0), C = viewmats.size(0);
  const int64_t K = sh_degree >= 0 ? colors.size(1) : 0;
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
  for (int64_t c = 0; c < C; ++c) cams[c] = load_cam(pv + 16 * c, pk + 9 * c);

  at::parallel_for(0, N, 512, [&](int64_t b0, int64_t b1) {
    Geo g;
    double Y[16];
    for (int64_t n = b0; n < b1; ++n) {
      rotmat(pq + 4 * n, g);
      for (int64_t c = 0; c < C; ++c) {
        const Cam& cam = cams[c];
        geometry(pm + 3 * n, ps + 3 * n, cam, st, g);
        const int64_t i = c * N + n;
        const double u = cam.fx * (g.in_depth ? g.p[0] : 0.0) * g.rz + cam.cx;
        const double v = cam.fy * (g.in_depth ? g.p[1] : 0.0) * g.rz + cam.cy;
        om[2 * i] = float(u);
        om[2 * i + 1] = float(v);
        oc[3 * i] = float(g.c / g.det);
        oc[3 * i + 1] = float(-g.b / g.det);
        oc[3 * i + 2] = float(g.a / g.det);
        od[i] = float(g.in_depth ? g.p[2] : 1.0);
        const double mid = 0.5 * (g.a + g.c), hd = 0.5 * (g.a - g.c);
        const double lam = mid + std::sqrt(std::max(hd * hd + g.b * g.b, 0.01));
        const double r = std::ceil(3.0 * std::sqrt(lam));
        const bool on_screen = (u + r > 0) && (u - r < double(width)) && (v + r > 0) && (v - r < double(height));
        orad[i] = (g.valid_T && on_screen) ? static_cast<int32_t>(r) : 0;
        double o = po[n];
        if (antialiased) o *= std::sqrt(std::max(g.det_raw / g.det, 1e-12));
        oo[i] = float(o);
        if (sh_degree >= 0) {
          double d[3] = {pm[3 * n] - cam.campos[0], pm[3 * n + 1] - cam.campos[1], pm[3 * n + 2] - cam.campos[2]};
          const double inv = 1.0 / std::max(std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]), NORM_EPS);
          sh_basis(static_cast<int>(sh_degree), d[0] * inv, d[1] * inv, d[2] * inv, Y, nullptr);
          const int nb = (sh_degree + 1) * (sh_degree + 1);
          const float* co = pc + n * K * 3;
          for (int ch = 0; ch < 3; ++ch) {
            double acc = 0.0;
            for (int k = 0; k < nb; ++k) acc += Y[k] * co[3 * k + ch];
            ocol[3 * i + ch] = float(std::max(acc + 0.5, 0.0));
          }
        } else {
          for (int ch = 0; ch < 3; ++ch) ocol[3 * i + ch] = pc[3 * n + ch];
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
  const int64_t K = sh_degree >= 0 ? colors.size(1) : 0;
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
  for (int64_t c = 0; c < C; ++c) cams[c] = load_cam(pv + 16 * c, pk + 9 * c);
  const double eps = eps2d;

  at::parallel_for(0, N, 512, [&](int64_t b0, int64_t b1) {
    Geo g;
    double Y[16], dY[16][3];
    std::vector<double> dco(std::max<int64_t>(K, 1) * 3);
    for (int64_t n = b0; n < b1; ++n) {
      rotmat(pq + 4 * n, g);
      double dmean[3] = {0, 0, 0}, dqn[4] = {0, 0, 0, 0}, dsc[3] = {0, 0, 0}, dopac = 0.0;
      std::fill(dco.begin(), dco.end(), 0.0);
      for (int64_t c = 0; c < C; ++c) {
        const Cam& cam = cams[c];
        const int64_t i = c * N + n;
        geometry(pm + 3 * n, ps + 3 * n, cam, st, g);
        double dR[3][3] = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}}, dt[3] = {0, 0, 0};

        // colours
        if (sh_degree >= 0) {
          const int nb = (sh_degree + 1) * (sh_degree + 1);
          double d[3] = {pm[3 * n] - cam.campos[0], pm[3 * n + 1] - cam.campos[1], pm[3 * n + 2] - cam.campos[2]};
          const double len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
          const double inv = 1.0 / std::max(len, NORM_EPS);
          const double dn[3] = {d[0] * inv, d[1] * inv, d[2] * inv};
          sh_basis(static_cast<int>(sh_degree), dn[0], dn[1], dn[2], Y, dY);
          const float* co = pc + n * K * 3;
          double gc[3];
          for (int ch = 0; ch < 3; ++ch) {
            double acc = 0.0;
            for (int k = 0; k < nb; ++k) acc += Y[k] * co[3 * k + ch];
            gc[ch] = (acc + 0.5 >= 0.0) ? double(gcol[3 * i + ch]) : 0.0;
          }
          double ddn[3] = {0, 0, 0};
          for (int k = 0; k < nb; ++k) {
            const double dyk = co[3 * k] * gc[0] + co[3 * k + 1] * gc[1] + co[3 * k + 2] * gc[2];
            for (int ch = 0; ch < 3; ++ch) dco[3 * k + ch] += Y[k] * gc[ch];
            for (int j = 0; j < 3; ++j) ddn[j] += dyk * dY[k][j];
          }
          double dd[3];
          if (len > NORM_EPS) {
            const double proj = dn[0] * ddn[0] + dn[1] * ddn[1] + dn[2] * ddn[2];
            for (int j = 0; j < 3; ++j) dd[j] = (ddn[j] - dn[j] * proj) * inv;
          } else {
            for (int j = 0; j < 3; ++j) dd[j] = ddn[j] * inv;
          }
          for (int j = 0; j < 3; ++j) dmean[j] += dd[j];
          // campos_i = -Σ_j R_ji t_j, d campos = -dd
          for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) {
              dR[b][a] += cam.t[b] * dd[a];
              dt[b] += cam.R[b][a] * dd[a];
            }
        } else {
          for (int ch = 0; ch < 3; ++ch) dco[ch] += gcol[3 * i + ch];
        }

        // opacity (with the antialiasing compensation)
        double ddet_raw = 0.0, ddet = 0.0;
        const double go = gop[i];
        if (antialiased) {
          const double ratio = g.det_raw / g.det;
          const double comp = std::sqrt(std::max(ratio, 1e-12));
          dopac += go * comp;
          if (ratio >= 1e-12) {
            const double dratio = go * po[n] * 0.5 / comp;
            ddet_raw += dratio / g.det;
            ddet += -dratio * g.det_raw / (g.det * g.det);
          }
        } else {
          dopac += go;
        }
        if (!g.in_depth) {
          if (pose_grad)
            for (int a = 0; a < 3; ++a) {
              for (int b = 0; b < 3; ++b) rows[12 * i + 3 * a + b] = dR[a][b];
              rows[12 * i + 9 + a] = dt[a];
            }
          continue;
        }

        // means2d and depth
        const double x = g.p[0], y = g.p[1], z = g.p[2], rz = g.rz;
        const double gu = gm2[2 * i], gv = gm2[2 * i + 1];
        double dp[3] = {gu * cam.fx * rz, gv * cam.fy * rz, double(gdep[i])};
        double drz = gu * cam.fx * x + gv * cam.fy * y;

        if (g.valid_T) {
          // conic = (c, -b, a) / det
          const double g0 = gcon[3 * i], g1 = gcon[3 * i + 1], g2 = gcon[3 * i + 2];
          const double da = g2 / g.det, dc = g0 / g.det, db = -g1 / g.det;
          ddet += -(g0 * g.c - g1 * g.b + g2 * g.a) / (g.det * g.det);
          ddet_raw += ddet;
          const double da_raw = da + eps * ddet, dc_raw = dc + eps * ddet;
          const double* t0 = g.T[0];
          const double* t1 = g.T[1];
          double dT[2][3];
          for (int j = 0; j < 3; ++j) {
            dT[0][j] = 2.0 * da_raw * t0[j] + db * t1[j];
            dT[1][j] = 2.0 * dc_raw * t1[j] + db * t0[j];
          }
          const double m01 = t0[0] * t1[1] - t0[1] * t1[0];
          const double m02 = t0[0] * t1[2] - t0[2] * t1[0];
          const double m12 = t0[1] * t1[2] - t0[2] * t1[1];
          const double d01 = 2.0 * m01 * ddet_raw, d02 = 2.0 * m02 * ddet_raw, d12 = 2.0 * m12 * ddet_raw;
          dT[0][0] += d01 * t1[1] + d02 * t1[2];
          dT[1][1] += d01 * t0[0] - d12 * t0[2];
          dT[0][1] += -d01 * t1[0] + d12 * t1[2];
          dT[1][0] += -d01 * t0[1] - d02 * t0[2];
          dT[1][2] += d02 * t0[0] + d12 * t0[1];
          dT[0][2] += -d02 * t1[0] - d12 * t1[1];
          // T = J WM
          double dJ[2][3], dWM[3][3];
          for (int a = 0; a < 2; ++a)
            for (int b = 0; b < 3; ++b)
              dJ[a][b] = dT[a][0] * g.WM[b][0] + dT[a][1] * g.WM[b][1] + dT[a][2] * g.WM[b][2];
          for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) dWM[a][b] = g.J[0][a] * dT[0][b] + g.J[1][a] * dT[1][b];
          // WM = R M
          double dM[3][3];
          for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) {
              dR[a][b] += dWM[a][0] * g.M[b][0] + dWM[a][1] * g.M[b][1] + dWM[a][2] * g.M[b][2];
              dM[a][b] = cam.R[0][a] * dWM[0][b] + cam.R[1][a] * dWM[1][b] + cam.R[2][a] * dWM[2][b];
            }
          // M = Rq diag(s)
          double dRq[3][3];
          for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) {
              dRq[a][b] = dM[a][b] * ps[3 * n + b];
              dsc[b] += dM[a][b] * g.Rq[a][b];
            }
          const double w = g.qn[0], qx = g.qn[1], qy = g.qn[2], qz = g.qn[3];
          dqn[0] += 2 * (-qz * dRq[0][1] + qy * dRq[0][2] + qz * dRq[1][0] - qx * dRq[1][2] - qy * dRq[2][0] +
                         qx * dRq[2][1]);
          dqn[1] += 2 * (qy * dRq[0][1] + qz * dRq[0][2] + qy * dRq[1][0] - 2 * qx * dRq[1][1] - w * dRq[1][2] +
                         qz * dRq[2][0] + w * dRq[2][1] - 2 * qx * dRq[2][2]);
          dqn[2] += 2 * (-2 * qy * dRq[0][0] + qx * dRq[0][1] + w * dRq[0][2] + qx * dRq[1][0] + qz * dRq[1][2] -
                         w * dRq[2][0] + qz * dRq[2][1] - 2 * qy * dRq[2][2]);
          dqn[3] += 2 * (-2 * qz * dRq[0][0] - w * dRq[0][1] + qx * dRq[0][2] + w * dRq[1][0] -
                         2 * qz * dRq[1][1] + qy * dRq[1][2] + qx * dRq[2][0] + qy * dRq[2][1]);
          // J(x, y, z): J00 = fx rz, J02 = -fx tx rz², J11 = fy rz, J12 = -fy ty rz²
          drz += cam.fx * dJ[0][0] + cam.fy * dJ[1][1];
          const double dtx = -cam.fx * rz * rz * dJ[0][2], dty = -cam.fy * rz * rz * dJ[1][2];
          drz += -2.0 * cam.fx * g.tx * rz * dJ[0][2] - 2.0 * cam.fy * g.ty * rz * dJ[1][2];
          // tx = z * clamp(x rz): the clamp passes the gradient only strictly inside its limits
          const double cxr = std::min(g.hi_x, std::max(g.lo_x, g.xr));
          const double cyr = std::min(g.hi_y, std::max(g.lo_y, g.yr));
          dp[2] += cxr * dtx + cyr * dty;
          if (g.xr > g.lo_x && g.xr < g.hi_x) {
            dp[0] += z * dtx * rz;
            drz += z * dtx * x;
          }
          if (g.yr > g.lo_y && g.yr < g.hi_y) {
            dp[1] += z * dty * rz;
            drz += z * dty * y;
          }
        }
        dp[2] += -rz * rz * drz;
        // p = R m + t
        for (int a = 0; a < 3; ++a) {
          dmean[a] += cam.R[0][a] * dp[0] + cam.R[1][a] * dp[1] + cam.R[2][a] * dp[2];
          for (int b = 0; b < 3; ++b) dR[a][b] += dp[a] * pm[3 * n + b];
          dt[a] += dp[a];
        }
        if (pose_grad)
          for (int a = 0; a < 3; ++a) {
            for (int b = 0; b < 3; ++b) rows[12 * i + 3 * a + b] = dR[a][b];
            rows[12 * i + 9 + a] = dt[a];
          }
      }
      // normalisation of the quaternion: q / max(|q|, eps)
      const double inv = 1.0 / std::max(g.qnorm, NORM_EPS);
      if (g.qnorm > NORM_EPS) {
        const double proj = g.qn[0] * dqn[0] + g.qn[1] * dqn[1] + g.qn[2] * dqn[2] + g.qn[3] * dqn[3];
        for (int j = 0; j < 4; ++j) odq[4 * n + j] = float((dqn[j] - g.qn[j] * proj) * inv);
      } else {
        for (int j = 0; j < 4; ++j) odq[4 * n + j] = float(dqn[j] * inv);
      }
      for (int j = 0; j < 3; ++j) {
        odm[3 * n + j] = float(dmean[j]);
        ods[3 * n + j] = float(dsc[j]);
      }
      odo[n] = float(dopac);
      if (sh_degree >= 0) {
        const int nb = (sh_degree + 1) * (sh_degree + 1);
        for (int k = 0; k < nb * 3; ++k) odc[n * K * 3 + k] = float(dco[k]);
        for (int k = nb * 3; k < K * 3; ++k) odc[n * K * 3 + k] = 0.0f;  // bands above the active degree
      } else {
        for (int ch = 0; ch < 3; ++ch) odc[3 * n + ch] = float(dco[ch]);
      }
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
