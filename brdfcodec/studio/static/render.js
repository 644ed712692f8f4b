// Sphere preview from decoded kept slices: the browser side of brdfcodec.render.preview.render_sphere.
//
// Follows spec/conventions.md as brdfcodec does: nearest MERL bin of the
// Rusinkiewicz angles (coords.py), linear interpolation between the 21 kept
// phi_d slices in the mapped domain, then unmapping (transforms.py), zero for
// bins below the horizon (mask.py) and for directions at or below it
// (lookup.py), orthographic view along -z, light from a direction, exposure
// then sRGB encoding (images.py).  Tests compare it with render_sphere.
"use strict";

const BvaeRender = (() => {
  const N_TH = 90, N_TD = 90, N_PD = 180, N_KEPT = 21;
  const KEPT = [];
  for (let p = 0; p < N_PD; p += 9) KEPT.push(p);
  KEPT.push(N_PD - 1);
  const EPSILON = 0.01;
  const LOG_RANGE = Math.log1p(1 / EPSILON);
  const MAPPED_MAX = 5.0;  // conventions.MAPPED_MAX
  const HORIZON_COS_MIN = 1e-9, BIN_TOLERANCE = 1e-9;
  const HALF_PI = Math.PI / 2;
  const SLICE = N_TH * N_TD;

  // For each phi_d bin: left kept slot, right kept slot, weight of the right one (transforms._interpolation_plan).
  const PLAN_LEFT = new Uint8Array(N_PD), PLAN_RIGHT = new Uint8Array(N_PD), PLAN_W = new Float64Array(N_PD);
  for (let p = 0; p < N_PD; p++) {
    const exact = KEPT.indexOf(p);
    if (exact >= 0) { PLAN_LEFT[p] = exact; PLAN_RIGHT[p] = exact; PLAN_W[p] = 0; continue; }
    let right = KEPT.findIndex((k) => k > p);
    right = Math.min(Math.max(right, 1), N_KEPT - 1);
    PLAN_LEFT[p] = right - 1; PLAN_RIGHT[p] = right;
    PLAN_W[p] = (p - KEPT[right - 1]) / (KEPT[right] - KEPT[right - 1]);
  }

  const elevation = (x, y, z) => Math.atan2(Math.hypot(x, y), z);
  const binOf = (coordinate, n) => Math.min(Math.max(Math.floor(coordinate + BIN_TOLERANCE), 0), n - 1);

  function normalize(v) {
    const n = Math.hypot(v[0], v[1], v[2]);
    return n > 0 ? [v[0] / n, v[1] / n, v[2] / n] : v;
  }

  // Table bins of a direction pair in the shading frame (coords.half_diff_from_directions + *_index).
  function bins(wi, wo) {
    const a = normalize(wi), b = normalize(wo);
    const h = normalize([a[0] + b[0], a[1] + b[1], a[2] + b[2]]);
    const thetaH = elevation(h[0], h[1], h[2]);
    const phiH = Math.atan2(h[1], h[0]);
    // rotate a by -phiH about z, then by -thetaH about y
    let c = Math.cos(-phiH), s = Math.sin(-phiH);
    const x1 = a[0] * c - a[1] * s, y1 = a[0] * s + a[1] * c, z1 = a[2];
    c = Math.cos(-thetaH); s = Math.sin(-thetaH);
    const dx = x1 * c + z1 * s, dy = y1, dz = -x1 * s + z1 * c;
    const thetaD = elevation(dx, dy, dz);
    let phiD = Math.atan2(dy, dx) % Math.PI;
    if (phiD < 0) phiD += Math.PI;
    if (phiD >= Math.PI) phiD = 0;
    const th = binOf(N_TH * Math.sqrt(Math.max(thetaH, 0) / HALF_PI), N_TH);
    const td = binOf(N_TD * Math.max(thetaD, 0) / HALF_PI, N_TD);
    const pd = binOf(N_PD * phiD / Math.PI, N_PD + 1) % N_PD;
    return [th, td, pd];
  }

  // Per-pixel lookup plan for a sphere of `size` pixels lit from `light` (render._sphere, _frames, _to_local).
  function sphereGeometry(size, light, mask) {
    const L = normalize(light);
    const pixels = [], base = [], left = [], right = [], weight = [], cosine = [];
    for (let j = 0; j < size; j++) {
      const y = -(((j + 0.5) / size) * 2 - 1);
      for (let i = 0; i < size; i++) {
        const x = ((i + 0.5) / size) * 2 - 1;
        const r2 = x * x + y * y;
        if (!(r2 < 1)) continue;
        const n = [x, y, Math.sqrt(Math.max(1 - r2, 0))];
        const helper = Math.abs(n[2]) < 0.9 ? [0, 0, 1] : [1, 0, 0];
        let t = [helper[1] * n[2] - helper[2] * n[1], helper[2] * n[0] - helper[0] * n[2], helper[0] * n[1] - helper[1] * n[0]];
        t = normalize(t);
        const b = [n[1] * t[2] - n[2] * t[1], n[2] * t[0] - n[0] * t[2], n[0] * t[1] - n[1] * t[0]];
        const wi = [L[0] * t[0] + L[1] * t[1] + L[2] * t[2], L[0] * b[0] + L[1] * b[1] + L[2] * b[2],
          L[0] * n[0] + L[1] * n[1] + L[2] * n[2]];
        const wo = [t[2], b[2], n[2]];
        let cos = Math.max(wi[2], 0);
        const above = wi[2] > HORIZON_COS_MIN && wo[2] > HORIZON_COS_MIN;
        let th = 0, td = 0, pd = 0;
        if (above) {
          [th, td, pd] = bins(wi, wo);
          const flat = (th * N_TD + td) * N_PD + pd;
          if (!((mask[flat >> 3] >> (flat & 7)) & 1)) cos = 0;  // bin below the horizon: 0
        } else {
          cos = 0;
        }
        pixels.push(j * size + i);
        base.push(th * N_TD + td);
        left.push(PLAN_LEFT[pd]); right.push(PLAN_RIGHT[pd]); weight.push(PLAN_W[pd]);
        cosine.push(cos);
      }
    }
    const inside = new Uint8Array(size * size);
    for (const p of pixels) inside[p] = 1;
    return {
      size, light: L, inside, pixels: Int32Array.from(pixels), base: Int32Array.from(base),
      left: Uint8Array.from(left), right: Uint8Array.from(right), weight: Float64Array.from(weight),
      cosine: Float64Array.from(cosine),
    };
  }

  // Linear radiance (size*size*3, float32) from kept slices (63*90*90 in network layout), quantised as the
  // server sends them: uint16 steps of MAPPED_MAX / 65535 (server.quantise_slices).
  const STEP = MAPPED_MAX / 65535;
  const CHANNEL = N_KEPT * SLICE;
  function renderSphere(geometry, slices, out) {
    const n = geometry.size * geometry.size * 3;
    const image = out && out.length === n ? out : new Float32Array(n);
    image.fill(0);
    const { pixels, base, left, right, weight, cosine } = geometry;
    for (let k = 0; k < pixels.length; k++) {
      const cos = cosine[k];
      if (cos === 0) continue;
      const w = weight[k], p = pixels[k] * 3;
      const a0 = left[k] * SLICE + base[k], b0 = right[k] * SLICE + base[k];
      for (let c = 0; c < 3; c++) {
        const a = slices[c * CHANNEL + a0] * STEP;
        const m = w === 0 ? a : a * (1 - w) + slices[c * CHANNEL + b0] * STEP * w;
        image[p + c] = EPSILON * Math.expm1(m * LOG_RANGE) * cos;
      }
    }
    return image;
  }

  // images.auto_exposure: the 99th percentile of the non-zero luminance maps to 1.
  function autoExposure(image) {
    const lum = [];
    for (let p = 0; p < image.length; p += 3) {
      const l = 0.2126 * image[p] + 0.7152 * image[p + 1] + 0.0722 * image[p + 2];
      if (l > 0) lum.push(l);
    }
    if (!lum.length) return 1;
    lum.sort((a, b) => a - b);
    const pos = 0.99 * (lum.length - 1), lo = Math.floor(pos), hi = Math.min(lo + 1, lum.length - 1);
    const level = lum[lo] + (lum[hi] - lum[lo]) * (pos - lo);  // numpy's linear percentile
    return level > 0 && Number.isFinite(level) ? 1 / level : 1;
  }

  const srgb = (v) => (v <= 0.0031308 ? 12.92 * v : 1.055 * Math.pow(v, 1 / 2.4) - 0.055);
  // 8-bit sRGB of exposed linear values in [0, 1], tabulated at 2^16 + 1 points (error < 0.3 of a level).
  const LUT_SIZE = 65536;
  const SRGB_LUT = new Uint8Array(LUT_SIZE + 1);
  for (let i = 0; i <= LUT_SIZE; i++) SRGB_LUT[i] = Math.round(srgb(i / LUT_SIZE) * 255);

  // Exposed, clipped, sRGB-encoded 8-bit pixels into an ImageData; transparent outside the sphere when
  // `inside` (a coverage mask) is given, so the page's background shows the silhouette.
  function encode(image, exposure, imageData, inside) {
    const data = imageData.data, scale = exposure * LUT_SIZE;
    for (let p = 0, q = 0; p < image.length; p += 3, q += 4) {
      for (let c = 0; c < 3; c++) {
        const v = image[p + c] * scale;
        data[q + c] = SRGB_LUT[v >= LUT_SIZE ? LUT_SIZE : v > 0 ? Math.round(v) : 0];
      }
      data[q + 3] = inside && !inside[q >> 2] ? 0 : 255;
    }
    return imageData;
  }

  return { sphereGeometry, renderSphere, autoExposure, encode, LATENT_SLICES: 3 * N_KEPT * SLICE };
})();
