// The tile bodies of rasterize_cpu.cpp: included there once per instruction set, each time inside its own
// namespace under `#pragma GCC target` (AVX2 with FMA, AVX2, portable x86-64), so every variant is compiled for
// its processor as a whole and may use that processor's instructions (here: one `vptest` for "is any lane set?",
// where the portable code needs four 64-bit extracts). No include guard: that is the point.

// Whether any of the 8 lanes of a mask is set.
GSGS_INLINE bool any_lane(vi mask) {
#if GSGS_TILE_AVX  // set by the includer for the AVX2 variants (GCC does not update __AVX__ for C++ pragmas)
  const __m256i m = (__m256i)mask;
  return !_mm256_testz_si256(m, m);
#else
  return any(mask);
#endif
}

// exp of a Gaussian exponent: clamped to [-87, 0] (NaN -> -87; the same values as selects, which the portable
// variant keeps: maxps returns its second operand for a NaN first one), then exp_clamped.
GSGS_INLINE vf exp_nonpositive(vf x) {
#if GSGS_TILE_AVX
  x = (vf)_mm256_min_ps(_mm256_max_ps((__m256)x, _mm256_set1_ps(-87.0f)), _mm256_setzero_ps());
#else
  x = select(x >= -87.0f, x, splat(-87.0f));
  x = select(x < 0.0f, x, splat(0.0f));
#endif
#if GSGS_TILE_AVX512
  vf n;
  const vf y = exp_mantissa(x, &n);
  return (vf)_mm256_scalef_ps((__m256)y, (__m256)n);  // y 2^n in one instruction, rounded as the product
#else
  return exp_clamped(x);
#endif
}

// alpha = min(0.99, o G) (NaN -> 0.99, as the select the portable variant keeps: minps returns its second operand).
GSGS_INLINE vf clamp_alpha(vf oG) {
#if GSGS_TILE_AVX
  return (vf)_mm256_min_ps((__m256)oG, _mm256_set1_ps(kMaxAlpha));
#else
  return select(oG < kMaxAlpha, oG, splat(kMaxAlpha));
#endif
}

// A tile composites a small share of the depth-ordered splat records, so consecutive entries lie far apart in
// memory and each record is a cache miss unless it was asked for early: fetch the one kFetchAhead entries on,
// both cache lines its 52 bytes may span. (Profiled on the rasterizer benchmark's 50k small splats: a quarter of
// both tile bodies' samples were on the first load of the record.) The backward also asks early for the gradient
// record it will write, which is as scattered (about 8 % off its time on the benchmark and a trained LLFF model).
constexpr int kFetchAhead = 8;
GSGS_INLINE void fetch_splat(const Splat* s) {
  __builtin_prefetch(s);
  __builtin_prefetch(reinterpret_cast<const char*>(s) + sizeof(Splat) - 1);
}

// Forward of one tile. Per-pixel state lives in lane vectors of 4 x 2-pixel blocks (four columns of two rows: a
// small splat's footprint fills more of a block's lanes than of an 8 x 1 row segment); each Gaussian updates only
// the blocks its alpha ellipse reaches, branch-free inside a block. Every pixel goes through the same operations in
// the same order as with row segments (the backward's layout), so the results are the same to the bit.
constexpr int kBlockW = 4, kBlockH = 2;
constexpr int kBlocksPerRow = kTile / kBlockW;
GSGS_INLINE int block_lane_x(int i) { return i % kBlockW; }
GSGS_INLINE int block_lane_y(int i) { return i / kBlockW; }
void forward_tile(GSGS_TILE_ARGS_F) {
  vf T[kVecs], cr[kVecs], cg[kVecs], cb[kVecs], dep[kVecs];
  vi active[kVecs], last[kVecs];
  const int rows = std::min(kTile, height - py0);
  const int cols = std::min(kTile, width - px0);
  for (int v = 0; v < kVecs; ++v) {
    T[v] = splat(1.0f);
    cr[v] = cg[v] = cb[v] = dep[v] = splat(0.0f);
    last[v] = splat_i(0);
    for (int i = 0; i < kLanes; ++i) {
      const int x = (v % kBlocksPerRow) * kBlockW + block_lane_x(i), y = (v / kBlocksPerRow) * kBlockH + block_lane_y(i);
      active[v][i] = (y < rows && x < cols) ? -1 : 0;  // pixels outside the image never blend
    }
  }
  vf px[kBlocksPerRow];  // pixel-centre x of each block column's lanes
  for (int c = 0; c < kBlocksPerRow; ++c)
    for (int i = 0; i < kLanes; ++i) px[c][i] = static_cast<float>(px0 + c * kBlockW + block_lane_x(i)) + 0.5f;
  vf py_off;  // pixel-centre y of a block's lanes, less the block row's first row
  for (int i = 0; i < kLanes; ++i) py_off[i] = static_cast<float>(block_lane_y(i));

  for (int j = 0; j < std::min(count, kFetchAhead); ++j) fetch_splat(splats + ranks[j]);
  for (int j = 0; j < count; ++j) {
    if (j + kFetchAhead < count) fetch_splat(splats + ranks[j + kFetchAhead]);
    const Splat s = splats[ranks[j]];
    int c_lo, c_hi, r_lo, r_hi;
    if (!reach_pixels(s, px0, py0, cols, rows, &c_lo, &c_hi, &r_lo, &r_hi)) continue;
    const int b_lo = c_lo / kBlockW, b_hi = c_hi / kBlockW;
    vi stopped = splat_i(0);
    const vi contributor = splat_i(j + 1);
    ColumnTerms col[kBlocksPerRow];
    for (int h = b_lo; h <= b_hi; ++h) col[h] = column_terms(s, px[h]);
    for (int br = r_lo / kBlockH; br <= r_hi / kBlockH; ++br) {
      // dy and C dy^2 per lane, as the row segments take them per row (the same values)
      const vf dy = s.my - ((static_cast<float>(py0 + br * kBlockH) + py_off) + 0.5f);
      const vf row_part = row_term(s, dy);
      for (int h = b_lo; h <= b_hi; ++h) {
        const int v = br * kBlocksPerRow + h;
        if (!any_lane(active[v])) continue;  // these 8 pixels are finished
        const vf power = gaussian_power(col[h], dy, row_part);
        if (!any_lane(power >= s.power_floor)) continue;  // no lane reaches alpha 1/255 (see power_floor)
        const vf oG = s.opacity * exp_nonpositive(power);
        const vf alpha = clamp_alpha(oG);
        const vi valid = active[v] & (power <= 0.0f) & (alpha >= kMinAlpha);
        const vf test_T = T[v] * (1.0f - alpha);
        const vi stop = valid & (test_T < kMinTransmittance);
        const vi add = valid & ~stop;
        const vf w = select(add, alpha * T[v], splat(0.0f));
        cr[v] += s.r * w;
        cg[v] += s.g * w;
        cb[v] += s.b * w;
        dep[v] += s.depth * w;
        T[v] = select(add, test_T, T[v]);
        last[v] = select_i(add, contributor, last[v]);
        active[v] &= ~stop;
        stopped |= stop;
      }
    }
    if (any_lane(stopped)) {  // some pixel just finished: is the whole tile done?
      vi still = splat_i(0);
      for (int v = 0; v < kVecs; ++v) still |= active[v];
      if (!any_lane(still)) break;
    }
  }

  for (int y = 0; y < rows; ++y) {
    for (int x = 0; x < cols; ++x) {
      const int v = (y / kBlockH) * kBlocksPerRow + x / kBlockW, i = (y % kBlockH) * kBlockW + x % kBlockW;
      const int64_t o = static_cast<int64_t>(py0 + y) * width + (px0 + x);
      const float t = T[v][i];
      out_color[o * 3 + 0] = cr[v][i] + t * background[0];
      out_color[o * 3 + 1] = cg[v][i] + t * background[1];
      out_color[o * 3 + 2] = cb[v][i] + t * background[2];
      out_depth[o] = dep[v][i];
      out_alpha[o] = 1.0f - t;
      out_T[o] = t;
      out_last[o] = last[v][i];
    }
  }
}

// Backward of one tile: back to front over the tile list, T reconstructed per pixel from the final
// transmittance; one gradient record (kGradFields floats) per list entry, written to its slot.
//   C = sum_i c_i a_i T_i + T_N bg,  D = sum_i z_i a_i T_i,  A_out = 1 - T_N
//   dC/da_i = T_i (c_i - S_i) - T_N bg / (1 - a_i), S_i = colour behind i (S_{i-1} = a_i c_i + (1-a_i) S_i)
//   dA_out/da_i = T_N / (1 - a_i)
// Only g . S_i enters (g the pixel's colour gradient, and its depth gradient with the depth: a 3- or 4-vector that
// is constant over the list), so a pixel carries that one dot product GS instead of the colour sums S r, g, b (and
// S z): GS_{i-1} = GS_i + a_i (g . c_i - GS_i). One state vector to load, blend and store a step, not three or four.
//
// With kAbsGrad (AbsGS's densification statistic) each entry also gets the sums over its pixels of the absolute
// per-pixel screen-space gradient, |dL_p/dmx| and |dL_p/dmy|, in abs_grad (2 floats per entry): per pixel
// dL_p/dm = -(A q dx + B q dy, B q dx + C q dy), where the plain gradient's row moments sum them before the sign
// could be taken. Compiled in only for the renders that ask for it (the training view's, when densifying by it).
template <bool kWithDepth, bool kAbsGrad>
void backward_tile_body(GSGS_TILE_ARGS_B) {
  (void)with_depth;  // kWithDepth: the depth terms compiled in or out, not tested per step
  (void)abs_grad;
  vf T[kVecs], GS[kVecs], gr[kVecs], gg[kVecs], gb[kVecs], gz[kVecs], K[kVecs];
  vi last[kVecs];
  const int rows = std::min(kTile, height - py0);
  const int cols = std::min(kTile, width - px0);
  for (int v = 0; v < kVecs; ++v) {
    T[v] = splat(1.0f);
    GS[v] = splat(0.0f);
    gr[v] = gg[v] = gb[v] = gz[v] = K[v] = splat(0.0f);
    last[v] = splat_i(0);  // pixels outside the image never take part
  }
  int max_last = 0;
  for (int y = 0; y < rows; ++y) {
    for (int x = 0; x < cols; ++x) {
      const int v = (y * kTile + x) / kLanes, i = x % kLanes;
      const int64_t o = static_cast<int64_t>(py0 + y) * width + (px0 + x);
      const float t = final_T[o];
      T[v][i] = t;
      last[v][i] = last_in[o];
      gr[v][i] = grad_color[o * 3 + 0];
      gg[v][i] = grad_color[o * 3 + 1];
      gb[v][i] = grad_color[o * 3 + 2];
      gz[v][i] = grad_depth[o];
      const float bg_dot = grad_color[o * 3 + 0] * background[0] + grad_color[o * 3 + 1] * background[1] +
                           grad_color[o * 3 + 2] * background[2];
      K[v][i] = t * (grad_alpha[o] - bg_dot);
      max_last = std::max(max_last, last_in[o]);
    }
  }
  vf px[kVecPerRow];
  pixel_centres(px0, px);

  // Entries behind every pixel's last contributor (transmittance spent) get a zero record, no work.
  for (int j = count - 1; j >= max_last; --j) {
    std::memset(entry_grad + static_cast<int64_t>(slots[j]) * kGradFields, 0, kGradFields * sizeof(float));
    if (kAbsGrad) abs_grad[2 * static_cast<int64_t>(slots[j])] = abs_grad[2 * static_cast<int64_t>(slots[j]) + 1] = 0;
  }
  const int first = std::min(count, max_last) - 1;
  for (int j = first; j >= std::max(first - kFetchAhead + 1, 0); --j) fetch_splat(splats + ranks[j]);
  for (int j = first; j >= 0; --j) {
    if (j >= kFetchAhead) {
      fetch_splat(splats + ranks[j - kFetchAhead]);
      const float* ahead = entry_grad + static_cast<int64_t>(slots[j - kFetchAhead]) * kGradFields;
      __builtin_prefetch(ahead, 1);
      __builtin_prefetch(ahead + kGradFields - 1, 1);
    }
    float* record = entry_grad + static_cast<int64_t>(slots[j]) * kGradFields;
    const Splat s = splats[ranks[j]];
    int r_lo = 0, r_hi = -1, v_lo = 0, v_hi = -1;
    reach(s, px0, py0, cols, rows, &r_lo, &r_hi, &v_lo, &v_hi);
    vf acc[kGradFields];
    for (int f = 0; f < kGradFields; ++f) acc[f] = splat(0.0f);
    vf abs_x = splat(0.0f), abs_y = splat(0.0f);  // kAbsGrad only (otherwise never read: compiled out)
    bool touched = false;
    const vi position = splat_i(j);
    ColumnTerms col[kVecPerRow];
    for (int h = v_lo; h <= v_hi; ++h) col[h] = column_terms(s, px[h]);
    for (int row = r_lo; row <= r_hi; ++row) {
      const float dy = s.my - (static_cast<float>(py0 + row) + 0.5f);
      const float row_part = row_term(s, dy);
      vf row_q = splat(0.0f), row_qx = splat(0.0f);  // this row's sums of q and q dx (dy is the row's)
      bool row_touched = false;
      for (int h = v_lo; h <= v_hi; ++h) {
        const int v = row * kVecPerRow + h;
        const vi listed = position < last[v];  // j blended into these pixels' colour (if valid)
        if (!any_lane(listed)) continue;
        const vf dx = col[h].dx;
        const vf power = gaussian_power(col[h], dy, row_part);
        if (!any_lane(listed & (power >= s.power_floor))) continue;  // no listed lane can reach alpha 1/255
        const vf G = exp_nonpositive(power);
        const vf oG = s.opacity * G;
        const vf alpha_lane = clamp_alpha(oG);
        const vi valid = listed & (power <= 0.0f) & (alpha_lane >= kMinAlpha);
        if (!any_lane(valid)) continue;
        row_touched = true;
        // alpha 0 on the lanes j did not blend into: there T_before == T and w == 0 exactly, so T and the
        // weights need no select (GS keeps its value by a select: 0 * a non-finite colour would not be 0).
        const vf alpha = select(valid, alpha_lane, splat(0.0f));
        const vf one_minus = 1.0f - alpha;  // >= 0.01
        const vf inv_one_minus = 1.0f / one_minus;  // one division, used twice
        const vf T_before = T[v] * inv_one_minus;
        const vf w = alpha * T_before;
        vf gc = gr[v] * s.r + gg[v] * s.g + gb[v] * s.b;
        if (kWithDepth) gc += gz[v] * s.depth;  // no depth loss (training): skipped
        const vf dot = gc - GS[v];  // g . (c_i - S_i)
        const vf dL_dalpha = T_before * dot + K[v] * inv_one_minus;
        // alpha = min(0.99, o G): no gradient through the clamp (as autograd of the reference).
        const vf dL_doG = select(valid & (oG <= kMaxAlpha), dL_dalpha, splat(0.0f));
        // dL/dpower times the offsets' moments; the mean and conic gradients are formed from them per entry:
        // d power / d mean = -(A dx + B dy, B dx + C dy), d power / d conic = -(dx^2 / 2, dx dy, dy^2 / 2).
        // The moments with dy (constant along a row) are taken once a row, from the row's sums of q and q dx.
        const vf q = dL_doG * oG;
        const vf qx = q * dx;
        row_q += q;
        row_qx += qx;
        if (kAbsGrad) {  // this step's pixels' own mean gradients (q is 0 on the lanes j did not blend into)
          const vf qy = q * dy;
          abs_x += vabs(s.A * qx + s.B * qy);
          abs_y += vabs(s.B * qx + s.C * qy);
        }
        acc[2] += qx * dx;
        acc[5] += gr[v] * w;
        acc[6] += gg[v] * w;
        acc[7] += gb[v] * w;
        if (kWithDepth) acc[9] += gz[v] * w;
        GS[v] = select(valid, GS[v] + alpha * dot, GS[v]);  // g . S_{i-1} = g . (a_i c_i + (1 - a_i) S_i)
        T[v] = T_before;
      }
      if (row_touched) {
        touched = true;
        acc[0] += row_qx;
        acc[1] += row_q * dy;
        acc[3] += row_qx * dy;
        acc[4] += row_q * (dy * dy);
        acc[8] += row_q;  // sum of q = o sum of dL/d(oG) G: divided by o below
      }
    }
    if (touched) {
      float m[8];
      hsum8(acc, m);  // sums of q dx, q dy, q dx^2, q dx dy, q dy^2, then the colour gradients
      record[0] = -(s.A * m[0] + s.B * m[1]);
      record[1] = -(s.B * m[0] + s.C * m[1]);
      record[2] = -0.5f * m[2];
      record[3] = -m[3];
      record[4] = -0.5f * m[4];
      record[5] = m[5];
      record[6] = m[6];
      record[7] = m[7];
      record[8] = hsum(acc[8]) / s.opacity;  // dL/do = sum dL/d(oG) G = sum q / o (o >= 1/255 when listed)
      record[9] = hsum(acc[9]);
    } else {
      std::memset(record, 0, kGradFields * sizeof(float));
    }
    if (kAbsGrad) {
      abs_grad[2 * static_cast<int64_t>(slots[j])] = touched ? hsum(abs_x) : 0.0f;
      abs_grad[2 * static_cast<int64_t>(slots[j]) + 1] = touched ? hsum(abs_y) : 0.0f;
    }
  }
}

// The backward with or without the depth terms (a training step has no depth loss), each compiled on its own so
// the per-step loop holds no test of it and the registers go to the terms it has.
void backward_tile(GSGS_TILE_ARGS_B) {
  if (abs_grad != nullptr) {
    if (with_depth) {
      backward_tile_body<true, true>(GSGS_TILE_PASS_B);
    } else {
      backward_tile_body<false, true>(GSGS_TILE_PASS_B);
    }
  } else if (with_depth) {
    backward_tile_body<true, false>(GSGS_TILE_PASS_B);
  } else {
    backward_tile_body<false, false>(GSGS_TILE_PASS_B);
  }
}
