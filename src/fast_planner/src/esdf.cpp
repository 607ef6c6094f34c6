#include "fast_planner/esdf.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace fast_planner {

namespace {
constexpr int32_t kInf = kEdtInfinity;
// "Beyond the truncation" inside the windowed passes: leaves room for + radius^2 without overflow.
constexpr int32_t kBig = 1 << 30;
// The windowed passes are used up to this truncation radius (voxels): they cost 2 radius + 1 row operations
// per row, the lower envelope a few per voxel whatever the radius (the bound is chosen, not measured; the
// planner's 2 m at 0.1 m is radius 20).
constexpr int kMaxWindowRadius = 40;

// o[x] = min(o[x], s[x] + dd) over a row: the inner loop of the windowed passes, compiled for AVX2 too (the
// loader picks the variant the CPU runs).
__attribute__((target_clones("avx2", "default"))) void MinPlus(int32_t* o, const int32_t* s, int32_t dd,
                                                               int nx) {
  for (int x = 0; x < nx; ++x) o[x] = std::min(o[x], s[x] + dd);
}

// One pass of the truncated squared distance transform along the rows of a block, for every x at once:
// out row q = min over |d| <= radius (0 <= q + d < len) of in row q + d plus d^2, then values above max_sq
// become kEdtInfinity. `in` holds len rows of nx values (below max_sq, or kBig); rows without a finite value
// (finite[q] == 0) are skipped as sources. Equal to the exact transform followed by the truncation: a sample
// farther than radius (radius^2 <= max_sq < (radius + 1)^2) adds more than max_sq.
void WindowedPass(const int32_t* in, const uint8_t* finite, int len, int nx, int radius, int32_t max_sq,
                  int32_t* out, int64_t out_stride) {
  for (int q = 0; q < len; ++q) {
    int32_t* o = out + q * out_stride;
    std::fill(o, o + nx, kBig);
    const int lo = std::max(0, q - radius), hi = std::min(len - 1, q + radius);
    for (int r = lo; r <= hi; ++r) {
      if (!finite[r]) continue;
      MinPlus(o, in + static_cast<int64_t>(r) * nx, (r - q) * (r - q), nx);
    }
    for (int x = 0; x < nx; ++x) o[x] = o[x] > max_sq ? kInf : o[x];
  }
}

// Copies `nx` values to `dst` with kEdtInfinity as kBig; returns whether any is finite.
uint8_t CopyAsBig(const int32_t* src, int nx, int32_t* dst) {
  int32_t lowest = kBig;
  for (int x = 0; x < nx; ++x) {
    dst[x] = std::min(src[x], kBig);
    lowest = std::min(lowest, dst[x]);
  }
  return lowest < kBig ? 1 : 0;
}
}  // namespace

void DistanceTransform1d(const int32_t* f, int n, int32_t* out, int* v, int64_t* z_num, int64_t* z_den) {
  // Lower envelope of the parabolas y = (q - p)^2 + f[p] rooted at the finite samples (Felzenszwalb &
  // Huttenlocher). The intersection of the parabolas of p < q lies at s = num / den with
  // num = (f[q] + q^2) - (f[p] + p^2) and den = 2 (q - p) > 0; comparisons are done on the cross products in
  // integers (exact, and no division). Envelope k spans [z_k, z_{k+1}), z_0 = -inf.
  int k = -1;
  for (int q = 0; q < n; ++q) {
    if (f[q] == kInf) continue;
    const int64_t fq = static_cast<int64_t>(f[q]) + static_cast<int64_t>(q) * q;
    if (k < 0) {
      k = 0;
      v[0] = q;
      continue;
    }
    int64_t num, den;
    while (true) {
      const int p = v[k];
      num = fq - (static_cast<int64_t>(f[p]) + static_cast<int64_t>(p) * p);
      den = 2 * static_cast<int64_t>(q - p);
      // Keep envelope k if s > z_k (always for k = 0).
      if (k == 0 || num * z_den[k] > z_num[k] * den) break;
      --k;
    }
    ++k;
    v[k] = q;
    z_num[k] = num;
    z_den[k] = den;
  }
  if (k < 0) {
    std::fill(out, out + n, kInf);
    return;
  }
  const int last = k;
  int j = 0;
  for (int q = 0; q < n; ++q) {
    while (j < last && z_num[j + 1] < static_cast<int64_t>(q) * z_den[j + 1]) ++j;  // z_{j+1} < q
    const int64_t d = q - v[j];
    out[q] = static_cast<int32_t>(d * d + f[v[j]]);
  }
}

Esdf::Esdf(double max_distance_m) : max_distance_m_(max_distance_m) {
  if (!(max_distance_m > 0.0)) throw std::invalid_argument("Esdf: max_distance_m must be positive");
}

void Esdf::Update(const VoxelMap& map, const Eigen::Vector3i& min_idx, const Eigen::Vector3i& max_idx) {
  if (!map.InMap(min_idx) || !map.InMap(max_idx) || (min_idx.array() > max_idx.array()).any()) {
    throw std::invalid_argument("Esdf::Update: window is empty or outside the map");
  }
  // The ground and the ceiling are planes: their distance is analytic, so their layers stay out of the
  // transform.
  const int ground = map.ground_layer();
  const int ceiling = map.ceiling_layer();
  Eigen::Vector3i lo = min_idx, hi = max_idx;
  lo.z() = std::max(lo.z(), ground + 1);
  hi.z() = std::min(hi.z(), ceiling - 1);
  if (lo.z() > hi.z()) {
    throw std::invalid_argument("Esdf::Update: window lies entirely in the ground or the ceiling");
  }
  resolution_ = map.resolution();
  origin_ = map.origin();
  min_ = lo;
  max_ = hi;
  n_ = max_ - min_ + Eigen::Vector3i::Ones();
  const int64_t total = static_cast<int64_t>(n_.x()) * n_.y() * n_.z();
  const int64_t slice = static_cast<int64_t>(n_.x()) * n_.y();

  map.ExtractObservedOccupancy(min_, max_, &occ_);
  sq_out_.resize(total);  // squared distance (voxels^2) to the nearest obstacle voxel
  sq_in_.resize(total);   // squared distance to the nearest free voxel
  // Squared distances above the truncation can only produce distances above it: they are dropped after every
  // pass (partial sums of squares never exceed the final one), which leaves far columns without a finite
  // value to skip.
  const double max_vox = max_distance_m_ / resolution_;
  const int32_t max_sq =
      max_vox * max_vox >= static_cast<double>(kInf) / 4 ? kInf - 1 : static_cast<int32_t>(max_vox * max_vox);
  const int longest = n_.maxCoeff();
  line_f_.resize(longest);
  line_d_.resize(longest);
  line_v_.resize(longest);
  line_zn_.resize(longest + 1);
  line_zd_.resize(longest + 1);

  // First pass along x on the binary input: the distance to the nearest seed in the row, by two linear scans.
  // Most rows hold no obstacle: no seed for the outside field (all infinite), every voxel its own seed for
  // the inside field (all zero); they are filled without the scans (the same values).
  for (int64_t row = 0; row < total; row += n_.x()) {
    const uint8_t* o = occ_.data() + row;
    if (std::find(o, o + n_.x(), uint8_t{1}) == o + n_.x()) {
      std::fill(sq_out_.data() + row, sq_out_.data() + row + n_.x(), kInf);
      std::fill(sq_in_.data() + row, sq_in_.data() + row + n_.x(), 0);
      continue;
    }
    for (const bool inside : {false, true}) {
      int32_t* data = (inside ? sq_in_ : sq_out_).data() + row;
      const uint8_t seed = inside ? 0 : 1;
      int last = -1;
      for (int q = 0; q < n_.x(); ++q) {
        if (o[q] == seed) last = q;
        data[q] = last < 0 ? kInf : q - last;
      }
      last = -1;
      for (int q = n_.x() - 1; q >= 0; --q) {
        if (o[q] == seed) last = q;
        const int32_t d = std::min(data[q], last < 0 ? kInf : last - q);
        data[q] = (d == kInf || static_cast<int64_t>(d) * d > max_sq) ? kInf : d * d;
      }
    }
  }

  // Then (the inside field, and the outside one without a short truncation) the lower envelope of parabolas
  // along y and z, column by column of an (len x nx) block whose rows are x rows of the field: for y the
  // block is a z slice in place, for z the rows are gathered into a buffer first (a z column strides over
  // whole slices, which thrashes the cache and the TLB). Columns that are all zero (inside obstacles for the
  // outside field, in free space for the inside field) or have no finite value stay; has_obstacle[x] lets the
  // inside field skip columns without an obstacle. Which columns stay is found row by row first (sequential
  // reads), so only the columns to transform are read with the block's stride.
  // Returns whether any column was transformed.
  std::vector<uint8_t> all_zero(n_.x()), any_finite(n_.x());
  auto columns = [&](int32_t* block, int len, bool inside, const std::vector<uint8_t>& has_obstacle) {
    const int nx = n_.x();
    std::fill(all_zero.begin(), all_zero.end(), uint8_t{1});
    std::fill(any_finite.begin(), any_finite.end(), uint8_t{0});
    for (int q = 0; q < len; ++q) {
      const int32_t* row = block + static_cast<int64_t>(q) * nx;
      for (int x = 0; x < nx; ++x) {
        all_zero[x] &= row[x] == 0 ? 1 : 0;
        any_finite[x] |= row[x] != kInf ? 1 : 0;
      }
    }
    bool changed = false;
    for (int x = 0; x < nx; ++x) {
      if ((inside && !has_obstacle[x]) || all_zero[x] || !any_finite[x]) continue;
      for (int q = 0; q < len; ++q) line_f_[q] = block[static_cast<int64_t>(q) * nx + x];
      DistanceTransform1d(line_f_.data(), len, line_d_.data(), line_v_.data(), line_zn_.data(),
                          line_zd_.data());
      for (int q = 0; q < len; ++q)
        block[static_cast<int64_t>(q) * nx + x] = line_d_[q] > max_sq ? kInf : line_d_[q];
      changed = true;
    }
    return changed;
  };
  // The outside field (every column near an obstacle) by windowed passes over whole rows when the truncation
  // is short; the inside field (only columns through obstacles) by the lower envelope, column by column.
  const int radius = static_cast<int>(std::floor(std::sqrt(static_cast<double>(max_sq))));
  const bool windowed = max_sq < kInf - 1 && radius <= kMaxWindowRadius;
  block_.resize(static_cast<size_t>(n_.x()) * std::max(n_.y(), n_.z()));
  std::vector<uint8_t> has_obstacle(n_.x()), finite(std::max(n_.y(), n_.z()));
  for (const bool inside : {false, true}) {
    std::vector<int32_t>& field = inside ? sq_in_ : sq_out_;
    if (!inside && windowed) {
      for (int z = 0; z < n_.z(); ++z) {  // along y: a z slice
        int32_t* s = field.data() + z * slice;
        for (int y = 0; y < n_.y(); ++y) {
          finite[y] = CopyAsBig(s + static_cast<int64_t>(y) * n_.x(), n_.x(), block_.data() + y * n_.x());
        }
        WindowedPass(block_.data(), finite.data(), n_.y(), n_.x(), radius, max_sq, s, n_.x());
      }
      for (int y = 0; y < n_.y(); ++y) {  // along z: the x rows of one y gathered
        int32_t* s = field.data() + static_cast<int64_t>(y) * n_.x();
        for (int z = 0; z < n_.z(); ++z) {
          finite[z] = CopyAsBig(s + z * slice, n_.x(), block_.data() + static_cast<int64_t>(z) * n_.x());
        }
        WindowedPass(block_.data(), finite.data(), n_.z(), n_.x(), radius, max_sq, s, slice);
      }
      continue;
    }
    for (int z = 0; z < n_.z(); ++z) {
      if (inside) {
        std::fill(has_obstacle.begin(), has_obstacle.end(), uint8_t{0});
        for (int y = 0; y < n_.y(); ++y) {
          const uint8_t* row = occ_.data() + z * slice + static_cast<int64_t>(y) * n_.x();
          for (int x = 0; x < n_.x(); ++x) has_obstacle[x] |= row[x];
        }
      }
      columns(field.data() + z * slice, n_.y(), inside, has_obstacle);
    }
    for (int y = 0; y < n_.y(); ++y) {
      if (inside) std::fill(has_obstacle.begin(), has_obstacle.end(), uint8_t{0});
      for (int z = 0; z < n_.z(); ++z) {
        const int64_t offset = z * slice + static_cast<int64_t>(y) * n_.x();
        std::copy(field.data() + offset, field.data() + offset + n_.x(),
                  block_.data() + static_cast<int64_t>(z) * n_.x());
        if (inside) {
          for (int x = 0; x < n_.x(); ++x) has_obstacle[x] |= occ_[offset + x];
        }
      }
      if (!columns(block_.data(), n_.z(), inside, has_obstacle)) continue;  // nothing to write back
      for (int z = 0; z < n_.z(); ++z) {
        const int32_t* row = block_.data() + static_cast<int64_t>(z) * n_.x();
        std::copy(row, row + n_.x(), field.data() + z * slice + static_cast<int64_t>(y) * n_.x());
      }
    }
  }

  dist_.resize(total);
  const float res = static_cast<float>(resolution_);
  const float far = static_cast<float>(std::min<double>(max_distance_m_, kFarDistance));
  for (int z = 0; z < n_.z(); ++z) {
    // The nearest ground (ceiling) voxel centre is straight below (above).
    const float plane = static_cast<float>(std::min(min_.z() + z - ground, ceiling - min_.z() - z)) * res;
    for (int64_t i = z * slice; i < (z + 1) * slice; ++i) {
      if (occ_[i]) {
        dist_[i] = sq_in_[i] == kInf ? -far : -std::sqrt(static_cast<float>(sq_in_[i])) * res;
      } else {
        const float d = sq_out_[i] == kInf ? far : std::sqrt(static_cast<float>(sq_out_[i])) * res;
        dist_[i] = std::min({d, plane, far});
      }
    }
  }
}

void Esdf::ReleaseScratch() {
  // swap with empty vectors: shrink_to_fit is only a request.
  std::vector<uint8_t>().swap(occ_);
  for (auto* v : {&sq_out_, &sq_in_, &block_, &line_f_, &line_d_}) std::vector<int32_t>().swap(*v);
  std::vector<int>().swap(line_v_);
  std::vector<int64_t>().swap(line_zn_);
  std::vector<int64_t>().swap(line_zd_);
}

float Esdf::VoxelDistance(const Eigen::Vector3i& idx) const {
  if (dist_.empty() || (idx.array() < min_.array()).any() || (idx.array() > max_.array()).any()) {
    return kFarDistance;
  }
  const Eigen::Vector3i l = idx - min_;
  return dist_[Local(l.x(), l.y(), l.z())];
}

double Esdf::Distance(const Eigen::Vector3d& p) const {
  Eigen::Vector3d unused;
  return DistanceAndGradient(p, &unused);
}

double Esdf::DistanceAndGradient(const Eigen::Vector3d& p, Eigen::Vector3d* grad) const {
  grad->setZero();
  if (dist_.empty()) return kFarDistance;
  // Continuous voxel coordinates in the window, voxel centres at integers.
  Eigen::Vector3d g = (p - origin_) / resolution_ - Eigen::Vector3d::Constant(0.5) - min_.cast<double>();
  Eigen::Vector3i i0;
  Eigen::Vector3d f;
  bool clamped[3];
  for (int a = 0; a < 3; ++a) {
    const double hi = n_[a] - 1;
    clamped[a] = !(g[a] > 0.0 && g[a] < hi);
    g[a] = std::clamp(g[a], 0.0, hi);
    i0[a] = std::min(static_cast<int>(std::floor(g[a])), std::max(n_[a] - 2, 0));
    f[a] = g[a] - i0[a];
  }
  const int dx = n_.x() > 1 ? 1 : 0;
  const int64_t dy = n_.y() > 1 ? n_.x() : 0;
  const int64_t dz = n_.z() > 1 ? static_cast<int64_t>(n_.x()) * n_.y() : 0;
  const int64_t b = Local(i0.x(), i0.y(), i0.z());
  const double v000 = dist_[b], v100 = dist_[b + dx], v010 = dist_[b + dy], v110 = dist_[b + dx + dy];
  const double v001 = dist_[b + dz], v101 = dist_[b + dx + dz], v011 = dist_[b + dy + dz],
               v111 = dist_[b + dx + dy + dz];
  const double c00 = v000 * (1 - f.x()) + v100 * f.x();
  const double c10 = v010 * (1 - f.x()) + v110 * f.x();
  const double c01 = v001 * (1 - f.x()) + v101 * f.x();
  const double c11 = v011 * (1 - f.x()) + v111 * f.x();
  const double c0 = c00 * (1 - f.y()) + c10 * f.y();
  const double c1 = c01 * (1 - f.y()) + c11 * f.y();
  const double d = c0 * (1 - f.z()) + c1 * f.z();
  if (!clamped[2]) (*grad)[2] = (c1 - c0) / resolution_;
  if (!clamped[1]) (*grad)[1] = ((c10 - c00) * (1 - f.z()) + (c11 - c01) * f.z()) / resolution_;
  if (!clamped[0]) {
    (*grad)[0] = ((v100 - v000) * (1 - f.y()) * (1 - f.z()) + (v110 - v010) * f.y() * (1 - f.z()) +
                  (v101 - v001) * (1 - f.y()) * f.z() + (v111 - v011) * f.y() * f.z()) /
                 resolution_;
  }
  return d;
}

}  // namespace fast_planner
