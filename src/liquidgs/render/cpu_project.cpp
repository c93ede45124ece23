// Projection and view-dependent colour on the CPU: projection.py's project_gaussians and
// rasterize.py's view_colors (SH + 0.5, clamped at 0) fused per Gaussian, forward and backward.
//
// The torch versions run some hundred small tensor ops each way; here every Gaussian is one
// loop iteration (OpenMP over Gaussians), so a training step's projection and colours cost
// about as much as one of those ops. The backward recomputes the forward's intermediates
// from the inputs instead of saving them. Gradients follow what autograd does to the torch
// code, clamps and masks included: nothing reaches the depth through z where a Gaussian is
// out of the depth range, the determinant only where it is positive, the Jacobian's x/z and
// y/z only inside their limits, and colours only where SH + 0.5 >= 0. The camera (view matrix
// and intrinsics) gets no gradient; rasterize() uses the torch path when it needs one.
//
// Built with cpu_composite.cpp into one library by liquidgs/render/cpu_backend.py.

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace {

// Camera block: world-to-camera rotation (row-major 3x3), translation, fx, fy, cx, cy.
template <typename S> struct Camera {
    S R[9], t[3], fx, fy, cx, cy;
};

template <typename S> struct Settings {
    int width, height;
    S near_plane, far_plane, eps2d;
};

template <typename S> Camera<S> read_camera(const S* block) {
    Camera<S> camera;
    for (int i = 0; i < 9; ++i) camera.R[i] = block[i];
    for (int i = 0; i < 3; ++i) camera.t[i] = block[9 + i];
    camera.fx = block[12];
    camera.fy = block[13];
    camera.cx = block[14];
    camera.cy = block[15];
    return camera;
}

// torch.nn.functional.normalize's floor on the norm.
template <typename S> constexpr S kNormEps = S(1e-12);

template <typename S> inline void quat_to_rotmat(const S q[4], S rot[9]) {
    const S w = q[0], x = q[1], y = q[2], z = q[3];
    rot[0] = 1 - 2 * (y * y + z * z);
    rot[1] = 2 * (x * y - w * z);
    rot[2] = 2 * (x * z + w * y);
    rot[3] = 2 * (x * y + w * z);
    rot[4] = 1 - 2 * (x * x + z * z);
    rot[5] = 2 * (y * z - w * x);
    rot[6] = 2 * (x * z - w * y);
    rot[7] = 2 * (y * z + w * x);
    rot[8] = 1 - 2 * (x * x + y * y);
}

// Everything the forward computes for one Gaussian, kept for the backward's chain rule.
template <typename S> struct Projected {
    S qn[4], qraw, qnorm;  // normalised quaternion, its input's norm and the norm it was divided by
    S rot[9];         // its rotation matrix
    S half[9];        // rot * diag(scales)
    S cov_cam[9];     // R half half^T R^T
    S x, y, z, z_safe;
    bool in_depth, clamped_x, clamped_y;
    S limit_x, limit_y;  // the limit x/z (y/z) was clamped to, when it was
    S tx, ty;
    S J[6];   // 2x3 Jacobian, row-major
    S jc[6];  // J cov_cam
    S a, b, c, det, det_safe;
    bool positive_det;
};

template <typename S>
inline void project_one(const S* mean, const S* quat, const S* scale, const Camera<S>& cam,
                        const Settings<S>& set, Projected<S>& p) {
    const S norm = std::sqrt(quat[0] * quat[0] + quat[1] * quat[1] + quat[2] * quat[2] + quat[3] * quat[3]);
    p.qraw = norm;
    p.qnorm = std::max(norm, kNormEps<S>);
    for (int i = 0; i < 4; ++i) p.qn[i] = quat[i] / p.qnorm;
    quat_to_rotmat(p.qn, p.rot);
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) p.half[3 * i + j] = p.rot[3 * i + j] * scale[j];
    S cov[9];  // half half^T
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
            S sum = 0;
            for (int k = 0; k < 3; ++k) sum += p.half[3 * i + k] * p.half[3 * j + k];
            cov[3 * i + j] = sum;
        }
    S rc[9];  // R cov
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
            S sum = 0;
            for (int k = 0; k < 3; ++k) sum += cam.R[3 * i + k] * cov[3 * k + j];
            rc[3 * i + j] = sum;
        }
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
            S sum = 0;
            for (int k = 0; k < 3; ++k) sum += rc[3 * i + k] * cam.R[3 * j + k];
            p.cov_cam[3 * i + j] = sum;
        }
    S cam_point[3];
    for (int i = 0; i < 3; ++i)
        cam_point[i] = cam.R[3 * i] * mean[0] + cam.R[3 * i + 1] * mean[1] + cam.R[3 * i + 2] * mean[2] + cam.t[i];
    p.x = cam_point[0];
    p.y = cam_point[1];
    p.z = cam_point[2];
    p.in_depth = p.z >= set.near_plane && p.z <= set.far_plane;  // gsplat keeps z == near and z == far
    p.z_safe = p.in_depth ? p.z : S(1);

    const S w = S(set.width), h = S(set.height);
    const S tan_x = S(0.5) * w / cam.fx, tan_y = S(0.5) * h / cam.fy;
    const S lim_x_pos = (w - cam.cx) / cam.fx + S(LIQUIDGS_FRUSTUM_MARGIN) * tan_x;
    const S lim_x_neg = cam.cx / cam.fx + S(LIQUIDGS_FRUSTUM_MARGIN) * tan_x;
    const S lim_y_pos = (h - cam.cy) / cam.fy + S(LIQUIDGS_FRUSTUM_MARGIN) * tan_y;
    const S lim_y_neg = cam.cy / cam.fy + S(LIQUIDGS_FRUSTUM_MARGIN) * tan_y;
    const S ratio_x = p.x / p.z_safe, ratio_y = p.y / p.z_safe;
    p.clamped_x = ratio_x < -lim_x_neg || ratio_x > lim_x_pos;
    p.clamped_y = ratio_y < -lim_y_neg || ratio_y > lim_y_pos;
    p.limit_x = ratio_x < -lim_x_neg ? -lim_x_neg : lim_x_pos;
    p.limit_y = ratio_y < -lim_y_neg ? -lim_y_neg : lim_y_pos;
    p.tx = p.z_safe * (p.clamped_x ? p.limit_x : ratio_x);
    p.ty = p.z_safe * (p.clamped_y ? p.limit_y : ratio_y);
    const S zz = p.z_safe * p.z_safe;
    p.J[0] = cam.fx / p.z_safe;
    p.J[1] = 0;
    p.J[2] = -cam.fx * p.tx / zz;
    p.J[3] = 0;
    p.J[4] = cam.fy / p.z_safe;
    p.J[5] = -cam.fy * p.ty / zz;
    for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 3; ++j) {
            S sum = 0;
            for (int k = 0; k < 3; ++k) sum += p.J[3 * i + k] * p.cov_cam[3 * k + j];
            p.jc[3 * i + j] = sum;
        }
    S cov2d[4];
    for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 2; ++j) {
            S sum = 0;
            for (int k = 0; k < 3; ++k) sum += p.jc[3 * i + k] * p.J[3 * j + k];
            cov2d[2 * i + j] = sum;
        }
    p.a = cov2d[0] + set.eps2d;
    p.b = cov2d[1];
    p.c = cov2d[3] + set.eps2d;
    p.det = p.a * p.c - p.b * p.b;
    p.positive_det = p.det > 0;
    p.det_safe = p.positive_det ? p.det : S(1);
}

template <typename S>
void project_forward(const S* means, const S* quats, const S* scales, const S* opacities, int64_t n,
                     const S* camera_block, const Settings<S>& set, S* means2d, S* conics, S* depths,
                     int32_t* radii_xy, uint8_t* visible, int threads) {
    const Camera<S> cam = read_camera(camera_block);
    const S alpha_threshold = S(LIQUIDGS_ALPHA_THRESHOLD);
    const S max_extent = S(LIQUIDGS_MAX_EXTENT_SIGMAS);
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int64_t i = 0; i < n; ++i) {
        Projected<S> p;
        project_one(means + 3 * i, quats + 4 * i, scales + 3 * i, cam, set, p);
        conics[3 * i] = p.c / p.det_safe;
        conics[3 * i + 1] = -p.b / p.det_safe;
        conics[3 * i + 2] = p.a / p.det_safe;
        const S u = cam.fx * p.x / p.z_safe + cam.cx;
        const S v = cam.fy * p.y / p.z_safe + cam.cy;
        means2d[2 * i] = u;
        means2d[2 * i + 1] = v;
        depths[i] = p.z;
        const S opacity = opacities[i];
        const S extent =
            std::min(std::sqrt(S(2) * std::log(std::max(opacity, alpha_threshold) / alpha_threshold)), max_extent);
        const S radius_x = std::ceil(extent * std::sqrt(std::max(p.a, S(0))));
        const S radius_y = std::ceil(extent * std::sqrt(std::max(p.c, S(0))));
        const bool on_screen = u + radius_x > 0 && u - radius_x < S(set.width) && v + radius_y > 0 &&
                               v - radius_y < S(set.height);
        const bool shown = p.in_depth && p.positive_det && opacity >= alpha_threshold &&
                           (radius_x > 0 || radius_y > 0) && on_screen;
        visible[i] = shown;
        radii_xy[2 * i] = shown ? int32_t(radius_x) : 0;
        radii_xy[2 * i + 1] = shown ? int32_t(radius_y) : 0;
    }
}

template <typename S>
void project_backward(const S* means, const S* quats, const S* scales, int64_t n, const S* camera_block,
                      const Settings<S>& set, const S* grad_means2d, const S* grad_conics, const S* grad_depths,
                      S* grad_means, S* grad_quats, S* grad_scales, int threads) {
    const Camera<S> cam = read_camera(camera_block);
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int64_t i = 0; i < n; ++i) {
        Projected<S> p;
        const S* scale = scales + 3 * i;
        project_one(means + 3 * i, quats + 4 * i, scale, cam, set, p);
        const S* gc = grad_conics + 3 * i;
        const S gu = grad_means2d[2 * i], gv = grad_means2d[2 * i + 1];

        // conics = (c, -b, a) / det_safe; det = a c - b^2 only where positive.
        const S d = p.det_safe;
        S ga = gc[2] / d, gb = -gc[1] / d, gcc = gc[0] / d;
        if (p.positive_det) {
            const S g_det = -(gc[0] * p.c - gc[1] * p.b + gc[2] * p.a) / (d * d);
            ga += g_det * p.c;
            gb += g_det * (-2 * p.b);
            gcc += g_det * p.a;
        }
        // cov2d = J cov_cam J^T, of which (0,0), (0,1) and (1,1) are used: G is upper triangular.
        const S G[4] = {ga, gb, 0, gcc};
        const S Gs[4] = {2 * ga, gb, gb, 2 * gcc};  // G + G^T
        S gJ[6];  // (G + G^T) J cov_cam
        for (int r = 0; r < 2; ++r)
            for (int j = 0; j < 3; ++j) gJ[3 * r + j] = Gs[2 * r] * p.jc[j] + Gs[2 * r + 1] * p.jc[3 + j];
        S gJ_G[6];  // G J
        for (int r = 0; r < 2; ++r)
            for (int j = 0; j < 3; ++j) gJ_G[3 * r + j] = G[2 * r] * p.J[j] + G[2 * r + 1] * p.J[3 + j];
        S g_cov_cam[9];  // J^T G J
        for (int r = 0; r < 3; ++r)
            for (int j = 0; j < 3; ++j) g_cov_cam[3 * r + j] = p.J[r] * gJ_G[j] + p.J[3 + r] * gJ_G[3 + j];

        // The Jacobian's entries through z_safe, tx and ty.
        const S zs = p.z_safe, zz = zs * zs, zzz = zz * zs;
        S g_zs = gJ[0] * (-cam.fx / zz) + gJ[2] * (2 * cam.fx * p.tx / zzz) + gJ[4] * (-cam.fy / zz) +
                 gJ[5] * (2 * cam.fy * p.ty / zzz);
        const S g_tx = gJ[2] * (-cam.fx / zz), g_ty = gJ[5] * (-cam.fy / zz);
        S g_cam[3] = {0, 0, 0};
        if (p.clamped_x) g_zs += g_tx * p.limit_x;
        else g_cam[0] += g_tx;
        if (p.clamped_y) g_zs += g_ty * p.limit_y;
        else g_cam[1] += g_ty;
        // means2d = (fx x / z_safe + cx, fy y / z_safe + cy).
        g_cam[0] += gu * cam.fx / zs;
        g_cam[1] += gv * cam.fy / zs;
        g_zs += -(gu * cam.fx * p.x + gv * cam.fy * p.y) / zz;
        g_cam[2] = grad_depths[i] + (p.in_depth ? g_zs : S(0));
        for (int j = 0; j < 3; ++j)
            grad_means[3 * i + j] = cam.R[j] * g_cam[0] + cam.R[3 + j] * g_cam[1] + cam.R[6 + j] * g_cam[2];

        // cov_cam = R cov R^T -> d cov = R^T g R; cov = half half^T -> d half = (g + g^T) half.
        S tmp[9], g_cov[9];
        for (int r = 0; r < 3; ++r)
            for (int j = 0; j < 3; ++j) {
                S sum = 0;
                for (int k = 0; k < 3; ++k) sum += g_cov_cam[3 * r + k] * cam.R[3 * k + j];
                tmp[3 * r + j] = sum;
            }
        for (int r = 0; r < 3; ++r)
            for (int j = 0; j < 3; ++j) {
                S sum = 0;
                for (int k = 0; k < 3; ++k) sum += cam.R[3 * k + r] * tmp[3 * k + j];
                g_cov[3 * r + j] = sum;
            }
        S g_half[9];
        for (int r = 0; r < 3; ++r)
            for (int j = 0; j < 3; ++j) {
                S sum = 0;
                for (int k = 0; k < 3; ++k) sum += (g_cov[3 * r + k] + g_cov[3 * k + r]) * p.half[3 * k + j];
                g_half[3 * r + j] = sum;
            }
        S g_rot[9];
        for (int j = 0; j < 3; ++j) {
            S sum = 0;
            for (int r = 0; r < 3; ++r) {
                g_rot[3 * r + j] = g_half[3 * r + j] * scale[j];
                sum += g_half[3 * r + j] * p.rot[3 * r + j];
            }
            grad_scales[3 * i + j] = sum;
        }
        // Rotation matrix -> normalised quaternion (w, x, y, z).
        const S w = p.qn[0], x = p.qn[1], y = p.qn[2], z = p.qn[3];
        const S* g = g_rot;
        S gq[4];
        gq[0] = 2 * (-z * g[1] + y * g[2] + z * g[3] - x * g[5] - y * g[6] + x * g[7]);
        gq[1] = 2 * (y * g[1] + z * g[2] + y * g[3] - 2 * x * g[4] - w * g[5] + z * g[6] + w * g[7] - 2 * x * g[8]);
        gq[2] = 2 * (-2 * y * g[0] + x * g[1] + w * g[2] + x * g[3] + z * g[5] - w * g[6] + z * g[7] - 2 * y * g[8]);
        gq[3] = 2 * (-2 * z * g[0] - w * g[1] + x * g[2] + w * g[3] - 2 * z * g[4] + y * g[5] + x * g[6] + y * g[7]);
        // q / max(|q|, eps): the norm's own gradient only where it is above the floor.
        const S dot = p.qraw >= kNormEps<S> ? w * gq[0] + x * gq[1] + y * gq[2] + z * gq[3] : S(0);
        for (int j = 0; j < 4; ++j) grad_quats[4 * i + j] = (gq[j] - p.qn[j] * dot) / p.qnorm;
    }
}

// Real SH constants, INRIA 3DGS / gsplat order and signs (sh.py).
constexpr double kC0 = 0.28209479177387814;
constexpr double kC1 = 0.4886025119029199;
constexpr double kC2[5] = {1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
                           0.5462742152960396};
constexpr double kC3[7] = {-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
                           -0.4570457994644658, 1.445305721320277, -0.5900435899266435};

// The bases at unit direction (x, y, z), and with grads non-null their derivatives d/dx, d/dy, d/dz.
template <typename S> inline void sh_bases(int degree, S x, S y, S z, S* bases, S (*grads)[3]) {
    bases[0] = S(kC0);
    if (grads) grads[0][0] = grads[0][1] = grads[0][2] = 0;
    if (degree < 1) return;
    const S c1 = S(kC1);
    bases[1] = -c1 * y;
    bases[2] = c1 * z;
    bases[3] = -c1 * x;
    if (grads) {
        const S d[3][3] = {{0, -c1, 0}, {0, 0, c1}, {-c1, 0, 0}};
        for (int k = 0; k < 3; ++k)
            for (int j = 0; j < 3; ++j) grads[1 + k][j] = d[k][j];
    }
    if (degree < 2) return;
    const S xx = x * x, yy = y * y, zz = z * z;
    const S c2[5] = {S(kC2[0]), S(kC2[1]), S(kC2[2]), S(kC2[3]), S(kC2[4])};
    bases[4] = c2[0] * x * y;
    bases[5] = c2[1] * y * z;
    bases[6] = c2[2] * (S(2) * zz - xx - yy);
    bases[7] = c2[3] * x * z;
    bases[8] = c2[4] * (xx - yy);
    if (grads) {
        const S d[5][3] = {{y, x, 0}, {0, z, y}, {-2 * x, -2 * y, 4 * z}, {z, 0, x}, {2 * x, -2 * y, 0}};
        for (int k = 0; k < 5; ++k)
            for (int j = 0; j < 3; ++j) grads[4 + k][j] = c2[k] * d[k][j];
    }
    if (degree < 3) return;
    const S c3[7] = {S(kC3[0]), S(kC3[1]), S(kC3[2]), S(kC3[3]), S(kC3[4]), S(kC3[5]), S(kC3[6])};
    bases[9] = c3[0] * y * (S(3) * xx - yy);
    bases[10] = c3[1] * x * y * z;
    bases[11] = c3[2] * y * (S(4) * zz - xx - yy);
    bases[12] = c3[3] * z * (S(2) * zz - S(3) * xx - S(3) * yy);
    bases[13] = c3[4] * x * (S(4) * zz - xx - yy);
    bases[14] = c3[5] * z * (xx - yy);
    bases[15] = c3[6] * x * (xx - S(3) * yy);
    if (grads) {
        const S d[7][3] = {
            {6 * x * y, 3 * xx - 3 * yy, 0},
            {y * z, x * z, x * y},
            {-2 * x * y, 4 * zz - xx - 3 * yy, 8 * y * z},
            {-6 * x * z, -6 * y * z, 6 * zz - 3 * xx - 3 * yy},
            {4 * zz - 3 * xx - yy, -2 * x * y, 8 * x * z},
            {2 * x * z, -2 * y * z, xx - yy},
            {3 * xx - 3 * yy, -6 * x * y, 0},
        };
        for (int k = 0; k < 7; ++k)
            for (int j = 0; j < 3; ++j) grads[9 + k][j] = c3[k] * d[k][j];
    }
}

// Unit direction from the camera centre; returns the norm it was divided by.
template <typename S> inline S view_direction(const S* mean, const S* centre, S unit[3]) {
    S dir[3] = {mean[0] - centre[0], mean[1] - centre[1], mean[2] - centre[2]};
    const S norm = std::sqrt(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
    const S divisor = std::max(norm, kNormEps<S>);
    for (int j = 0; j < 3; ++j) unit[j] = dir[j] / divisor;
    return norm;
}

template <typename S>
void sh_forward(const S* means, const S* coeffs, int64_t n, int n_coeffs, int degree, const S* centre,
                S* colors, int threads) {
    const int n_bases = (degree + 1) * (degree + 1);
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int64_t i = 0; i < n; ++i) {
        S unit[3], bases[16];
        view_direction(means + 3 * i, centre, unit);
        sh_bases<S>(degree, unit[0], unit[1], unit[2], bases, nullptr);
        const S* row = coeffs + i * n_coeffs * 3;
        for (int ch = 0; ch < 3; ++ch) {
            S sum = 0;
            for (int k = 0; k < n_bases; ++k) sum += bases[k] * row[3 * k + ch];
            colors[3 * i + ch] = std::max(sum + S(0.5), S(0));
        }
    }
}

template <typename S>
void sh_backward(const S* means, const S* coeffs, int64_t n, int n_coeffs, int degree, const S* centre,
                 const S* grad_colors, S* grad_means, S* grad_coeffs, int threads) {
    const int n_bases = (degree + 1) * (degree + 1);
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int64_t i = 0; i < n; ++i) {
        S unit[3], bases[16], d_bases[16][3];
        const S norm = view_direction(means + 3 * i, centre, unit);
        sh_bases<S>(degree, unit[0], unit[1], unit[2], bases, d_bases);
        const S* row = coeffs + i * n_coeffs * 3;
        S* grad_row = grad_coeffs + i * n_coeffs * 3;
        S g_color[3];
        for (int ch = 0; ch < 3; ++ch) {
            S sum = 0;
            for (int k = 0; k < n_bases; ++k) sum += bases[k] * row[3 * k + ch];
            g_color[ch] = sum + S(0.5) >= 0 ? grad_colors[3 * i + ch] : S(0);
        }
        S g_unit[3] = {0, 0, 0};
        for (int k = 0; k < n_coeffs; ++k) {
            if (k >= n_bases) {
                for (int ch = 0; ch < 3; ++ch) grad_row[3 * k + ch] = 0;
                continue;
            }
            S g_basis = 0;
            for (int ch = 0; ch < 3; ++ch) {
                grad_row[3 * k + ch] = bases[k] * g_color[ch];
                g_basis += row[3 * k + ch] * g_color[ch];
            }
            for (int j = 0; j < 3; ++j) g_unit[j] += g_basis * d_bases[k][j];
        }
        // unit = dir / max(|dir|, eps).
        const S divisor = std::max(norm, kNormEps<S>);
        const S dot = norm >= kNormEps<S> ? unit[0] * g_unit[0] + unit[1] * g_unit[1] + unit[2] * g_unit[2] : S(0);
        for (int j = 0; j < 3; ++j) grad_means[3 * i + j] = (g_unit[j] - unit[j] * dot) / divisor;
    }
}

}  // namespace

#define LIQUIDGS_PROJECT_EXPORTS(S, SUFFIX)                                                                        \
    extern "C" void liquidgs_project_forward_##SUFFIX(const S* means, const S* quats, const S* scales,             \
                                                      const S* opacities, int64_t n, const S* camera, int width,  \
                                                      int height, S near_plane, S far_plane, S eps2d,             \
                                                      S* means2d, S* conics, S* depths, int32_t* radii_xy,        \
                                                      uint8_t* visible, int threads) {                            \
        project_forward<S>(means, quats, scales, opacities, n, camera,                                            \
                           Settings<S>{width, height, near_plane, far_plane, eps2d}, means2d, conics, depths,     \
                           radii_xy, visible, threads);                                                           \
    }                                                                                                              \
    extern "C" void liquidgs_project_backward_##SUFFIX(                                                            \
        const S* means, const S* quats, const S* scales, int64_t n, const S* camera, int width, int height,        \
        S near_plane, S far_plane, S eps2d, const S* grad_means2d, const S* grad_conics, const S* grad_depths,     \
        S* grad_means, S* grad_quats, S* grad_scales, int threads) {                                               \
        project_backward<S>(means, quats, scales, n, camera, Settings<S>{width, height, near_plane, far_plane, eps2d}, \
                            grad_means2d, grad_conics, grad_depths, grad_means, grad_quats, grad_scales, threads); \
    }                                                                                                              \
    extern "C" void liquidgs_sh_forward_##SUFFIX(const S* means, const S* coeffs, int64_t n, int n_coeffs,         \
                                                 int degree, const S* centre, S* colors, int threads) {           \
        sh_forward<S>(means, coeffs, n, n_coeffs, degree, centre, colors, threads);                                \
    }                                                                                                              \
    extern "C" void liquidgs_sh_backward_##SUFFIX(const S* means, const S* coeffs, int64_t n, int n_coeffs,        \
                                                  int degree, const S* centre, const S* grad_colors,              \
                                                  S* grad_means, S* grad_coeffs, int threads) {                   \
        sh_backward<S>(means, coeffs, n, n_coeffs, degree, centre, grad_colors, grad_means, grad_coeffs, threads); \
    }

LIQUIDGS_PROJECT_EXPORTS(float, f32)
LIQUIDGS_PROJECT_EXPORTS(double, f64)
