// Tile-based differentiable Gaussian rasterizer for the CPU (float and double).
//
// The rules (shared with reconstruct/raster/reference.py, which is the test oracle):
//  * a Gaussian counts at the pixels of its box (inclusive pixel ranges computed in projection.py);
//  * per pixel, Gaussians are taken in increasing camera depth (ties: increasing index);
//  * alpha = min(0.99, opacity * exp(-0.5 d^T conic d)), d = pixel centre - mean;
//  * a Gaussian with alpha < 1/255 is skipped at that pixel;
//  * before including a Gaussian, if T * (1 - alpha) < 1e-4 the pixel stops (that Gaussian is not
//    included, nor any later one);
//  * C = sum_i f_i alpha_i T_i + T_final * background, alpha_out = sum_i alpha_i T_i.
//
// Work is split into 16x16 tiles. Binning sorts the visible Gaussians by depth once and appends
// each one to the lists of the tiles its box overlaps, so every list comes out depth-sorted. Within
// a tile the forward walks the list front to back and, for each Gaussian, only the pixels of its
// box; the backward walks it back to front, recovering each T_i by division (3DGS). Per-(tile,
// Gaussian) gradient contributions go to their own row of a buffer and are summed per Gaussian in
// a fixed order, so results do not depend on the number of threads.
#include <torch/extension.h>

#include <ATen/Parallel.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <numeric>
#include <vector>

namespace {

constexpr int kTile = 16;
constexpr int kTilePixels = kTile * kTile;
constexpr double kMinAlpha = 1.0 / 255.0;
constexpr double kMaxAlpha = 0.99;
constexpr double kMinTransmittance = 1e-4;
constexpr int kParams = 6;  // per-Gaussian gradient row: mean x, mean y, conic a, b, c, opacity

// Run fn(item, scratch) for every item in [0, n) on torch's intra-op threads; items are handed out
// one at a time so that uneven tiles balance. Each worker owns one Scratch.
template <typename Scratch, typename MakeScratch, typename Fn>
void parallel_dynamic(int64_t n, const MakeScratch& make_scratch, const Fn& fn) {
  if (n <= 0) return;
  std::atomic<int64_t> next{0};
  const int64_t workers = std::max<int64_t>(1, std::min<int64_t>(at::get_num_threads(), n));
  at::parallel_for(0, workers, 1, [&](int64_t, int64_t) {
    Scratch scratch = make_scratch();
    for (int64_t item = next++; item < n; item = next++) fn(item, scratch);
  });
}

struct TileGrid {
  int width, height, nx, ny;
  TileGrid(int w, int h) : width(w), height(h), nx((w + kTile - 1) / kTile), ny((h + kTile - 1) / kTile) {}
  int64_t count() const { return int64_t(nx) * ny; }
  int x0(int64_t t) const { return int(t % nx) * kTile; }
  int y0(int64_t t) const { return int(t / nx) * kTile; }
};

// Pixel box of one Gaussian (inclusive), as produced by projection.pixel_boxes.
struct Box {
  int x_lo, x_hi, y_lo, y_hi;
  bool empty() const { return x_lo > x_hi || y_lo > y_hi; }
};

inline Box load_box(const int32_t* boxes, int64_t g) {
  const int32_t* b = boxes + 4 * g;
  return {b[0], b[1], b[2], b[3]};
}

// Box of Gaussian g clipped to the tile whose top-left pixel is (tx0, ty0).
inline Box clip_to_tile(const Box& b, int tx0, int ty0, const TileGrid& grid) {
  return {std::max(b.x_lo, tx0), std::min(b.x_hi, std::min(tx0 + kTile, grid.width) - 1),
          std::max(b.y_lo, ty0), std::min(b.y_hi, std::min(ty0 + kTile, grid.height) - 1)};
}

// exp(x) for x <= 0 in float without calls or branches, so that loops over it vectorise: Cephes'
// expf (range reduction by ln 2, degree-6 polynomial), relative error below 2e-7.
inline float exp_nonpositive(float x) {
  x = std::max(x, -87.0f);
  const float n = std::floor(x * 1.44269504088896341f + 0.5f);
  const float r = (x - n * 0.693359375f) - n * -2.12194440e-4f;
  float p = 1.9875691500e-4f;
  p = p * r + 1.3981999507e-3f;
  p = p * r + 8.3334519073e-3f;
  p = p * r + 4.1665795894e-2f;
  p = p * r + 1.6666665459e-1f;
  p = p * r + 5.0000001201e-1f;
  p = p * (r * r) + r + 1.0f;
  const int32_t bits = (int32_t(n) + 127) << 23;
  float scale;
  std::memcpy(&scale, &bits, sizeof scale);
  return p * scale;
}

// v[i] <- exp(-v[i]) for v[i] >= 0.
inline void exp_negative(float* v, int n) {
  for (int i = 0; i < n; ++i) v[i] = exp_nonpositive(-v[i]);
}
inline void exp_negative(double* v, int n) {
  for (int i = 0; i < n; ++i) v[i] = std::exp(-v[i]);
}

template <typename T>
struct Splat {
  T mx, my, a, b, c, opacity;
  const T* feature;

  Splat(const T* means2d, const T* conics, const T* opacities, const T* features, int64_t g, int64_t C)
      : mx(means2d[2 * g]), my(means2d[2 * g + 1]), a(conics[3 * g]), b(conics[3 * g + 1]),
        c(conics[3 * g + 2]), opacity(opacities[g]), feature(features + g * C) {}

  // 0.5 d^T conic d with d = (dx, dy); written exactly like the torch reference.
  T sigma(T dx, T dy) const { return T(0.5) * (a * dx * dx + c * dy * dy) + b * dx * dy; }

  // exp(-sigma) at pixels x_lo .. x_lo+n-1 of row y into out[0..n); returns the bit mask of those
  // pixels where alpha reaches the 1/255 threshold (bit i for pixel x_lo+i). The forward and the
  // backward both evaluate whole box rows with this, so they see bit-identical values.
  uint32_t evaluate_row(int y, int x_lo, int n, T* out) const {
    const T dy = (T(y) + T(0.5)) - my;
    for (int i = 0; i < n; ++i) out[i] = sigma((T(x_lo + i) + T(0.5)) - mx, dy);
    exp_negative(out, n);
    uint32_t visible = 0;  // min(0.99, o g) >= 1/255  <=>  o g >= 1/255
    for (int i = 0; i < n; ++i) visible |= uint32_t(opacity * out[i] >= T(kMinAlpha)) << i;
    return visible;
  }
};

// Bits lo..hi (inclusive) set: the tile columns of a box row.
inline uint32_t column_mask(int lo, int hi) { return ((2u << hi) - 1u) & ~((1u << lo) - 1u); }

inline int lowest_bit(uint32_t bits) { return __builtin_ctz(bits); }

// ----------------------------------------------------------------------------------------------
// Binning
// ----------------------------------------------------------------------------------------------

// Unsigned integers ordered like the floating-point values (NaN excluded).
inline uint32_t order_key(float v) {
  uint32_t bits;
  std::memcpy(&bits, &v, sizeof bits);
  return (bits & 0x80000000u) ? ~bits : (bits | 0x80000000u);
}
inline uint64_t order_key(double v) {
  uint64_t bits;
  std::memcpy(&bits, &v, sizeof bits);
  return (bits >> 63) ? ~bits : (bits | (uint64_t(1) << 63));
}

// Stable least-significant-digit radix sort of `values` by `keys` (11-bit digits).
template <typename Key>
void radix_sort(std::vector<Key>& keys, std::vector<int64_t>& values) {
  constexpr int kBits = 11, kBuckets = 1 << kBits;
  const size_t n = keys.size();
  std::vector<Key> keys_out(n);
  std::vector<int64_t> values_out(n);
  for (int shift = 0; shift < int(8 * sizeof(Key)); shift += kBits) {
    std::vector<size_t> offset(kBuckets + 1, 0);
    for (size_t i = 0; i < n; ++i) ++offset[((keys[i] >> shift) & (kBuckets - 1)) + 1];
    if (*std::max_element(offset.begin(), offset.end()) == n) continue;  // one digit value: order kept
    std::partial_sum(offset.begin(), offset.end(), offset.begin());
    for (size_t i = 0; i < n; ++i) {
      const size_t to = offset[(keys[i] >> shift) & (kBuckets - 1)]++;
      keys_out[to] = keys[i];
      values_out[to] = values[i];
    }
    keys.swap(keys_out);
    values.swap(values_out);
  }
}

// Indices of the Gaussians with a non-empty box, by increasing depth, ties by increasing index.
template <typename T>
std::vector<int64_t> depth_order(const T* depths, const int32_t* boxes, int64_t n) {
  std::vector<decltype(order_key(T()))> keys;
  std::vector<int64_t> order;
  keys.reserve(n);
  order.reserve(n);
  for (int64_t g = 0; g < n; ++g)
    if (!load_box(boxes, g).empty()) {
      keys.push_back(order_key(depths[g]));
      order.push_back(g);
    }
  radix_sort(keys, order);
  return order;
}

// Returns tile_offsets (tiles+1), tile_gaussians (M, int32), tile_slots (M) and
// gaussian_offsets (N+1): entry k of tile t's list (tile_offsets[t] <= k < tile_offsets[t+1]) is
// Gaussian tile_gaussians[k]; tile_slots[k] is its row in the Gaussian-major gradient buffer, where
// Gaussian g owns rows gaussian_offsets[g] .. gaussian_offsets[g+1]-1.
std::vector<torch::Tensor> bin_gaussians(torch::Tensor boxes, torch::Tensor depths, int64_t width, int64_t height) {
  TORCH_CHECK(boxes.dtype() == torch::kInt32 && boxes.dim() == 2 && boxes.size(1) == 4 && boxes.is_contiguous(),
              "boxes must be a contiguous (N,4) int32 tensor");
  TORCH_CHECK(depths.dim() == 1 && depths.size(0) == boxes.size(0) && depths.is_contiguous(),
              "depths must be a contiguous (N,) tensor");
  const TileGrid grid{int(width), int(height)};
  const int64_t n = boxes.size(0);
  const int32_t* box_ptr = boxes.data_ptr<int32_t>();
  const auto i64 = torch::TensorOptions().dtype(torch::kInt64);

  torch::Tensor gaussian_offsets = torch::zeros({n + 1}, i64);
  torch::Tensor tile_offsets = torch::zeros({grid.count() + 1}, i64);
  int64_t* goff = gaussian_offsets.data_ptr<int64_t>();
  int64_t* toff = tile_offsets.data_ptr<int64_t>();
  for (int64_t g = 0; g < n; ++g) {
    const Box b = load_box(box_ptr, g);
    int64_t count = 0;
    if (!b.empty()) {
      TORCH_CHECK(b.x_lo >= 0 && b.x_hi < width && b.y_lo >= 0 && b.y_hi < height,
                  "box of Gaussian ", g, " is not clipped to the image");
      for (int ty = b.y_lo / kTile; ty <= b.y_hi / kTile; ++ty)
        for (int tx = b.x_lo / kTile; tx <= b.x_hi / kTile; ++tx) ++toff[int64_t(ty) * grid.nx + tx + 1];
      count = int64_t(b.y_hi / kTile - b.y_lo / kTile + 1) * (b.x_hi / kTile - b.x_lo / kTile + 1);
    }
    goff[g + 1] = goff[g] + count;
  }
  std::partial_sum(toff, toff + grid.count() + 1, toff);
  const int64_t m = goff[n];

  std::vector<int64_t> order;
  AT_DISPATCH_FLOATING_TYPES(depths.scalar_type(), "bin_gaussians", [&] {
    order = depth_order(depths.data_ptr<scalar_t>(), box_ptr, n);
  });

  torch::Tensor tile_gaussians = torch::empty({m}, torch::TensorOptions().dtype(torch::kInt32));
  torch::Tensor tile_slots = torch::empty({m}, i64);
  int32_t* ids = tile_gaussians.data_ptr<int32_t>();
  int64_t* slots = tile_slots.data_ptr<int64_t>();
  std::vector<int64_t> cursor(toff, toff + grid.count());
  for (int64_t g : order) {
    const Box b = load_box(box_ptr, g);
    int64_t slot = goff[g];
    for (int ty = b.y_lo / kTile; ty <= b.y_hi / kTile; ++ty)
      for (int tx = b.x_lo / kTile; tx <= b.x_hi / kTile; ++tx) {
        const int64_t k = cursor[int64_t(ty) * grid.nx + tx]++;
        ids[k] = int32_t(g);
        slots[k] = slot++;
      }
  }
  return {tile_offsets, tile_gaussians, tile_slots, gaussian_offsets};
}

// ----------------------------------------------------------------------------------------------
// Forward
// ----------------------------------------------------------------------------------------------

// Channel count: a compile-time constant NC for the common sizes, else the runtime value.
template <int NC>
inline int64_t channels(const torch::Tensor& features) {
  return NC > 0 ? NC : features.size(1);
}

// The read-only inputs a tile pass needs for its Gaussians (forward and backward alike): the
// projected splats and the tile's depth-sorted list of Gaussian ids.
template <typename T>
struct TileInputs {
  const T* means2d;
  const T* conics;
  const T* opacities;
  const T* features;
  const int32_t* boxes;
  const int32_t* ids;
  int64_t begin;  // the tile's first entry in ids

  template <typename Args>
  TileInputs(const Args& args, int64_t tile)
      : means2d(args.means2d.template data_ptr<T>()),
        conics(args.conics.template data_ptr<T>()),
        opacities(args.opacities.template data_ptr<T>()),
        features(args.features.template data_ptr<T>()),
        boxes(args.boxes.template data_ptr<int32_t>()),
        ids(args.tile_gaussians.template data_ptr<int32_t>()),
        begin(args.tile_offsets.template data_ptr<int64_t>()[tile]) {}

  // The k-th Gaussian of the tile's list, and its box clipped to the tile.
  Splat<T> splat(int64_t k, int64_t C) const { return Splat<T>(means2d, conics, opacities, features, ids[k], C); }
  Box box(int64_t k, int tx0, int ty0, const TileGrid& grid) const {
    return clip_to_tile(load_box(boxes, ids[k]), tx0, ty0, grid);
  }
};

template <typename T>
struct ForwardScratch {
  std::vector<T> transmittance, color, weight, row;
  std::vector<int64_t> last, hit;
  explicit ForwardScratch(int64_t C)
      : transmittance(kTilePixels), color(kTilePixels * C), weight(kTilePixels), row(kTile), last(kTilePixels),
        hit(kTilePixels) {}
};

struct ForwardArgs {
  torch::Tensor means2d, conics, opacities, features, background, boxes, tile_offsets, tile_gaussians;
  torch::Tensor image, alpha, transmittance, last, first_hit;
  bool want_hit;
  double hit_threshold;
};

template <typename T, int NC>
void write_forward_tile(int64_t tile, const TileGrid& grid, const ForwardArgs& args, const ForwardScratch<T>& s) {
  const int64_t C = channels<NC>(args.features);
  const T* background = args.background.data_ptr<T>();
  T* image = args.image.data_ptr<T>();
  T* alpha = args.alpha.data_ptr<T>();
  T* transmittance = args.transmittance.data_ptr<T>();
  int64_t* last = args.last.data_ptr<int64_t>();
  int64_t* hit = args.want_hit ? args.first_hit.data_ptr<int64_t>() : nullptr;
  const int tx0 = grid.x0(tile), ty0 = grid.y0(tile);
  const int tw = std::min(kTile, grid.width - tx0), th = std::min(kTile, grid.height - ty0);
  for (int y = 0; y < th; ++y)
    for (int x = 0; x < tw; ++x) {
      const int p = y * kTile + x;
      const int64_t q = int64_t(ty0 + y) * grid.width + (tx0 + x);
      const T t = s.transmittance[p];
      for (int64_t ch = 0; ch < C; ++ch) image[q * C + ch] = s.color[p * C + ch] + t * background[ch];
      alpha[q] = s.weight[p];
      transmittance[q] = t;
      last[q] = s.last[p];
      if (hit) hit[q] = s.hit[p];
    }
}

template <typename T, int NC>
void forward_tile(int64_t tile, const TileGrid& grid, const ForwardArgs& args, ForwardScratch<T>& s) {
  const int64_t C = channels<NC>(args.features);
  const TileInputs<T> in(args, tile);
  const int64_t begin = in.begin;
  const int64_t end = args.tile_offsets.template data_ptr<int64_t>()[tile + 1];
  const int tx0 = grid.x0(tile), ty0 = grid.y0(tile);
  const int tw = std::min(kTile, grid.width - tx0), th = std::min(kTile, grid.height - ty0);
  const T hit_threshold = T(args.hit_threshold);

  T* __restrict__ trans = s.transmittance.data();
  T* __restrict__ color = s.color.data();
  T* __restrict__ weight = s.weight.data();
  T* __restrict__ row = s.row.data();
  int64_t* __restrict__ last = s.last.data();
  int64_t* __restrict__ hit = s.hit.data();
  std::fill(trans, trans + kTilePixels, T(1));
  std::fill(color, color + kTilePixels * C, T(0));
  std::fill(weight, weight + kTilePixels, T(0));
  std::fill(last, last + kTilePixels, begin);
  std::fill(hit, hit + kTilePixels, int64_t(-1));
  uint32_t alive[kTile] = {};  // per tile row, one bit per pixel that has not terminated
  for (int y = 0; y < th; ++y) alive[y] = column_mask(0, tw - 1);
  int alive_count = tw * th;

  for (int64_t k = begin; k < end && alive_count > 0; ++k) {
    const int64_t g = in.ids[k];
    const Splat<T> sp = in.splat(k, C);
    const Box b = in.box(k, tx0, ty0, grid);
    const uint32_t columns = column_mask(b.x_lo - tx0, b.x_hi - tx0);
    for (int y = b.y_lo; y <= b.y_hi; ++y) {
      uint32_t bits = alive[y - ty0] & columns;
      if (!bits) continue;
      bits &= sp.evaluate_row(y, b.x_lo, b.x_hi - b.x_lo + 1, row) << (b.x_lo - tx0);
      for (; bits; bits &= bits - 1) {
        const int lx = lowest_bit(bits);
        const T a = std::min(T(kMaxAlpha), sp.opacity * row[lx + tx0 - b.x_lo]);
        const int p = (y - ty0) * kTile + lx;
        const T t = trans[p];
        const T next_t = t * (T(1) - a);
        if (next_t < T(kMinTransmittance)) {  // the pixel stops before this Gaussian
          alive[y - ty0] &= ~(1u << lx);
          --alive_count;
          continue;
        }
        const T w = a * t;
        for (int64_t ch = 0; ch < C; ++ch) color[p * C + ch] += w * sp.feature[ch];
        weight[p] += w;
        trans[p] = next_t;
        last[p] = k + 1;
        if (hit[p] < 0 && T(1) - next_t >= hit_threshold) hit[p] = g;  // opacity reaches the threshold
      }
    }
  }
  write_forward_tile<T, NC>(tile, grid, args, s);
}

void check_inputs(const torch::Tensor& means2d, const torch::Tensor& conics, const torch::Tensor& opacities,
                  const torch::Tensor& features, const torch::Tensor& background) {
  const int64_t n = means2d.size(0);
  for (const auto* t : {&means2d, &conics, &opacities, &features, &background}) {
    TORCH_CHECK(t->is_contiguous() && t->device().is_cpu(), "rasterizer inputs must be contiguous CPU tensors");
    TORCH_CHECK(t->scalar_type() == means2d.scalar_type(), "rasterizer inputs must share one dtype");
  }
  TORCH_CHECK(means2d.dim() == 2 && means2d.size(1) == 2, "means2d must be (N,2)");
  TORCH_CHECK(conics.dim() == 2 && conics.size(0) == n && conics.size(1) == 3, "conics must be (N,3)");
  TORCH_CHECK(opacities.dim() == 1 && opacities.size(0) == n, "opacities must be (N,)");
  TORCH_CHECK(features.dim() == 2 && features.size(0) == n && features.size(1) >= 1, "features must be (N,C)");
  TORCH_CHECK(background.dim() == 1 && background.size(0) == features.size(1), "background must be (C,)");
}

// Calls fn.template operator()<NC>() with NC the channel count if it is one of the specialised
// sizes (1-4, 6 or 7 features plus the depth channel), else with NC = 0 (runtime count).
template <typename Fn>
void dispatch_channels(int64_t C, const Fn& fn) {
  switch (C) {
    case 2: return fn.template operator()<2>();
    case 3: return fn.template operator()<3>();
    case 4: return fn.template operator()<4>();
    case 5: return fn.template operator()<5>();
    case 7: return fn.template operator()<7>();
    case 8: return fn.template operator()<8>();
    default: return fn.template operator()<0>();
  }
}

// Returns image (H,W,C), alpha (H,W), final transmittance (H,W), last (H,W) int64 = one past the
// list index of the pixel's last contributor, and first_hit (H,W) int64 (-1 where none; an empty
// tensor unless want_hit).
std::vector<torch::Tensor> rasterize_forward(torch::Tensor means2d, torch::Tensor conics, torch::Tensor opacities,
                                             torch::Tensor features, torch::Tensor background, torch::Tensor boxes,
                                             torch::Tensor tile_offsets, torch::Tensor tile_gaussians, int64_t width,
                                             int64_t height, bool want_hit, double hit_threshold) {
  check_inputs(means2d, conics, opacities, features, background);
  const TileGrid grid{int(width), int(height)};
  const auto opts = means2d.options();
  const int64_t C = features.size(1);
  // without want_hit no Gaussian reaches the threshold, so every id stays -1
  ForwardArgs args{means2d, conics, opacities, features, background, boxes, tile_offsets, tile_gaussians,
                   torch::empty({height, width, C}, opts), torch::empty({height, width}, opts),
                   torch::empty({height, width}, opts), torch::empty({height, width}, opts.dtype(torch::kInt64)),
                   want_hit ? torch::empty({height, width}, opts.dtype(torch::kInt64))
                            : torch::empty({0}, opts.dtype(torch::kInt64)),
                   want_hit, want_hit ? hit_threshold : std::numeric_limits<double>::infinity()};
  AT_DISPATCH_FLOATING_TYPES(means2d.scalar_type(), "rasterize_forward", [&] {
    dispatch_channels(C, [&]<int NC>() {
      using Scratch = ForwardScratch<scalar_t>;
      parallel_dynamic<Scratch>(
          grid.count(), [&] { return Scratch(C); },
          [&](int64_t tile, Scratch& s) { forward_tile<scalar_t, NC>(tile, grid, args, s); });
    });
  });
  return {args.image, args.alpha, args.transmittance, args.last, args.first_hit};
}

// ----------------------------------------------------------------------------------------------
// Backward
// ----------------------------------------------------------------------------------------------

template <typename T>
struct BackwardScratch {
  std::vector<T> transmittance, behind, behind_alpha, grad_color, grad_alpha, grad_feature, row;
  std::vector<int64_t> last;
  std::vector<int> starting, next_starting;  // pixels chained by the list index where they start
  explicit BackwardScratch(int64_t C)
      : transmittance(kTilePixels), behind(kTilePixels * C), behind_alpha(kTilePixels),
        grad_color(kTilePixels * C), grad_alpha(kTilePixels), grad_feature(C), row(kTile), last(kTilePixels),
        next_starting(kTilePixels) {}
};

struct BackwardArgs {
  torch::Tensor means2d, conics, opacities, features, background, boxes, tile_offsets, tile_gaussians, tile_slots;
  torch::Tensor transmittance, last, grad_image, grad_alpha;
  torch::Tensor buffer;  // (M, kParams + C) per-(tile, Gaussian) gradient rows
};

// Loads the per-pixel state of a tile at the end of the forward; returns the largest `last`.
template <typename T>
int64_t load_backward_state(int64_t tile, const TileGrid& grid, const BackwardArgs& args, BackwardScratch<T>& s) {
  const int64_t C = args.features.size(1);
  const T* background = args.background.data_ptr<T>();
  const T* trans = args.transmittance.data_ptr<T>();
  const int64_t* last = args.last.data_ptr<int64_t>();
  const T* grad_image = args.grad_image.data_ptr<T>();
  const T* grad_alpha = args.grad_alpha.data_ptr<T>();
  const int tx0 = grid.x0(tile), ty0 = grid.y0(tile);
  const int tw = std::min(kTile, grid.width - tx0), th = std::min(kTile, grid.height - ty0);
  std::fill(s.last.begin(), s.last.end(), int64_t(0));  // pixels outside the image never contribute
  int64_t max_last = 0;
  for (int y = 0; y < th; ++y)
    for (int x = 0; x < tw; ++x) {
      const int p = y * kTile + x;
      const int64_t q = int64_t(ty0 + y) * grid.width + (tx0 + x);
      s.transmittance[p] = trans[q];
      s.last[p] = last[q];
      max_last = std::max(max_last, last[q]);
      for (int64_t ch = 0; ch < C; ++ch) {
        s.behind[p * C + ch] = background[ch];
        s.grad_color[p * C + ch] = grad_image[q * C + ch];
      }
      s.behind_alpha[p] = T(0);
      s.grad_alpha[p] = grad_alpha[q];
    }
  return max_last;
}

// Gradient of one Gaussian w.r.t. its 2D mean, conic and opacity, summed over a tile's pixels.
template <typename T>
struct ShapeGrad {
  T mx = 0, my = 0, a = 0, b = 0, c = 0, opacity = 0;

  // Adds the contribution of one pixel at offset (dx, dy) with d(loss)/d(alpha) = grad_alpha.
  void add(const Splat<T>& sp, T dx, T dy, T gauss, T grad_alpha) {
    const T grad_sigma = -sp.opacity * gauss * grad_alpha;  // alpha = o exp(-sigma)
    mx -= (sp.a * dx + sp.b * dy) * grad_sigma;             // d sigma / d mean = -conic d
    my -= (sp.b * dx + sp.c * dy) * grad_sigma;
    a += T(0.5) * dx * dx * grad_sigma;
    b += dx * dy * grad_sigma;
    c += T(0.5) * dy * dy * grad_sigma;
    opacity += gauss * grad_alpha;
  }
};

template <typename T, int NC>
void backward_tile(int64_t tile, const TileGrid& grid, const BackwardArgs& args, BackwardScratch<T>& s) {
  const int64_t C = channels<NC>(args.features);
  const TileInputs<T> in(args, tile);
  const int64_t* slots = args.tile_slots.data_ptr<int64_t>();
  T* buffer = args.buffer.data_ptr<T>();
  const int64_t begin = in.begin;
  const int tx0 = grid.x0(tile), ty0 = grid.y0(tile);
  const int64_t end = load_backward_state(tile, grid, args, s);

  T* __restrict__ trans = s.transmittance.data();
  T* __restrict__ behind = s.behind.data();
  T* __restrict__ behind_alpha = s.behind_alpha.data();
  const T* __restrict__ grad_color = s.grad_color.data();
  const T* __restrict__ grad_alpha = s.grad_alpha.data();
  T* __restrict__ grad_feature = s.grad_feature.data();
  T* __restrict__ row = s.row.data();
  const int64_t* __restrict__ last = s.last.data();
  // Pixel p becomes active once k < last[p]: chain the pixels by the list index where they start.
  s.starting.assign(std::max<int64_t>(end - begin, 0), -1);
  for (int p = 0; p < kTilePixels; ++p)
    if (last[p] > begin) {
      s.next_starting[p] = s.starting[last[p] - 1 - begin];
      s.starting[last[p] - 1 - begin] = p;
    }
  uint32_t active[kTile] = {};

  for (int64_t k = end - 1; k >= begin; --k) {
    for (int p = s.starting[k - begin]; p >= 0; p = s.next_starting[p]) active[p / kTile] |= 1u << (p % kTile);
    const int64_t g = in.ids[k];
    const Splat<T> sp = in.splat(k, C);
    const Box b = in.box(k, tx0, ty0, grid);
    const uint32_t columns = column_mask(b.x_lo - tx0, b.x_hi - tx0);
    ShapeGrad<T> shape;
    std::fill(grad_feature, grad_feature + C, T(0));
    bool touched = false;
    for (int y = b.y_lo; y <= b.y_hi; ++y) {
      uint32_t bits = active[y - ty0] & columns;
      if (!bits) continue;
      bits &= sp.evaluate_row(y, b.x_lo, b.x_hi - b.x_lo + 1, row) << (b.x_lo - tx0);
      const T dy = (T(y) + T(0.5)) - sp.my;
      touched |= bits != 0;
      for (; bits; bits &= bits - 1) {
        const int lx = lowest_bit(bits);
        const int p = (y - ty0) * kTile + lx;
        const T gauss = row[lx + tx0 - b.x_lo];
        const T raw = sp.opacity * gauss;
        const T a = std::min(T(kMaxAlpha), raw);
        const T one_minus = T(1) - a;
        const T t = trans[p] / one_minus;  // transmittance in front of this Gaussian
        trans[p] = t;
        // d(out)/d(alpha) = T (f - what lies behind); the alpha output is a channel with f = 1, bg = 0.
        T grad_a = (T(1) - behind_alpha[p]) * grad_alpha[p];
        behind_alpha[p] = a + one_minus * behind_alpha[p];
        for (int64_t ch = 0; ch < C; ++ch) {
          const T gc = grad_color[p * C + ch], f = sp.feature[ch];
          grad_feature[ch] += a * t * gc;
          grad_a += (f - behind[p * C + ch]) * gc;
          behind[p * C + ch] = a * f + one_minus * behind[p * C + ch];
        }
        if (raw <= T(kMaxAlpha))  // a clamped alpha passes no gradient to opacity or shape
          shape.add(sp, (T(lx + tx0) + T(0.5)) - sp.mx, dy, gauss, grad_a * t);
      }
    }
    if (!touched) continue;
    T* out = buffer + slots[k] * (kParams + C);
    const T params[kParams] = {shape.mx, shape.my, shape.a, shape.b, shape.c, shape.opacity};
    std::copy(params, params + kParams, out);
    std::copy(grad_feature, grad_feature + C, out + kParams);
  }
}

// Sums the gradient rows of each Gaussian in a fixed order.
template <typename T>
void reduce_rows(const BackwardArgs& args, const torch::Tensor& gaussian_offsets, torch::Tensor& grad_means2d,
                 torch::Tensor& grad_conics, torch::Tensor& grad_opacities, torch::Tensor& grad_features) {
  const int64_t C = args.features.size(1);
  const int64_t stride = kParams + C;
  const T* buffer = args.buffer.data_ptr<T>();
  const int64_t* goff = gaussian_offsets.data_ptr<int64_t>();
  T* gm = grad_means2d.data_ptr<T>();
  T* gc = grad_conics.data_ptr<T>();
  T* go = grad_opacities.data_ptr<T>();
  T* gf = grad_features.data_ptr<T>();
  at::parallel_for(0, grad_opacities.size(0), 1024, [&](int64_t lo, int64_t hi) {
    std::vector<T> sum(stride);
    for (int64_t g = lo; g < hi; ++g) {
      std::fill(sum.begin(), sum.end(), T(0));
      for (int64_t r = goff[g]; r < goff[g + 1]; ++r)
        for (int64_t j = 0; j < stride; ++j) sum[j] += buffer[r * stride + j];
      gm[2 * g] = sum[0];
      gm[2 * g + 1] = sum[1];
      gc[3 * g] = sum[2];
      gc[3 * g + 1] = sum[3];
      gc[3 * g + 2] = sum[4];
      go[g] = sum[5];
      std::copy(sum.begin() + kParams, sum.end(), gf + g * C);
    }
  });
}

// Gradients w.r.t. means2d (N,2), conics (N,3), opacities (N,) and features (N,C). The background
// gradient (sum over pixels of T_final * grad_image) is left to the caller.
std::vector<torch::Tensor> rasterize_backward(torch::Tensor means2d, torch::Tensor conics, torch::Tensor opacities,
                                              torch::Tensor features, torch::Tensor background, torch::Tensor boxes,
                                              torch::Tensor tile_offsets, torch::Tensor tile_gaussians,
                                              torch::Tensor tile_slots, torch::Tensor gaussian_offsets,
                                              torch::Tensor transmittance, torch::Tensor last,
                                              torch::Tensor grad_image, torch::Tensor grad_alpha, int64_t width,
                                              int64_t height) {
  check_inputs(means2d, conics, opacities, features, background);
  TORCH_CHECK(grad_image.is_contiguous() && grad_alpha.is_contiguous(), "gradients must be contiguous");
  TORCH_CHECK(grad_image.scalar_type() == means2d.scalar_type() && grad_alpha.scalar_type() == means2d.scalar_type(),
              "gradients must have the dtype of the inputs");
  const TileGrid grid{int(width), int(height)};
  const int64_t C = features.size(1);
  const int64_t m = tile_gaussians.size(0);
  BackwardArgs args{means2d, conics, opacities, features, background, boxes, tile_offsets, tile_gaussians, tile_slots,
                    transmittance, last, grad_image, grad_alpha, torch::zeros({m, kParams + C}, means2d.options())};
  torch::Tensor grad_means2d = torch::empty_like(means2d), grad_conics = torch::empty_like(conics);
  torch::Tensor grad_opacities = torch::empty_like(opacities), grad_features = torch::empty_like(features);
  AT_DISPATCH_FLOATING_TYPES(means2d.scalar_type(), "rasterize_backward", [&] {
    dispatch_channels(C, [&]<int NC>() {
      using Scratch = BackwardScratch<scalar_t>;
      parallel_dynamic<Scratch>(
          grid.count(), [&] { return Scratch(C); },
          [&](int64_t tile, Scratch& s) { backward_tile<scalar_t, NC>(tile, grid, args, s); });
    });
    reduce_rows<scalar_t>(args, gaussian_offsets, grad_means2d, grad_conics, grad_opacities, grad_features);
  });
  return {grad_means2d, grad_conics, grad_opacities, grad_features};
}

}  // namespace

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("bin_gaussians", &bin_gaussians, "Depth-sorted per-tile Gaussian lists");
  m.def("forward", &rasterize_forward, "Rasterize binned Gaussians (forward)");
  m.def("backward", &rasterize_backward, "Rasterize binned Gaussians (backward)");
}
