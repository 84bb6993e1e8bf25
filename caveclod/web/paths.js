// Camera paths over a mesh's bounding box: caveclod/paths.py in JavaScript,
// so that `?trajectory=` flies exactly the poses of `caveclod loadtest`.
// Each maps (lo, hi, camera, t seconds) to {eye, target, up}.

const UP = [0, 0, 1];

function box(lo, hi) {
  const extent = Math.max(hi[0] - lo[0], hi[1] - lo[1], 1e-9);
  const centre = [0, 1, 2].map((i) => 0.5 * (lo[i] + hi[i]));
  return { extent, centre, terrain: hi[2] - lo[2] < extent / 3 };
}

export function flyover(lo, hi, camera, t, secondsPerLap = 60) {
  const { extent } = box(lo, hi);
  const quadrant = camera % 4;
  const cx = lo[0] + (hi[0] - lo[0]) * (0.25 + 0.5 * (quadrant % 2));
  const cy = lo[1] + (hi[1] - lo[1]) * (0.25 + 0.5 * Math.floor(quadrant / 2));
  const radius = 0.2 * extent;
  const direction = camera % 2 === 0 ? 1 : -1;
  const phase = (direction * 2 * Math.PI * t) / secondsPerLap + camera * 1.3;
  const ex = cx + radius * Math.cos(phase), ey = cy + radius * Math.sin(phase);
  const hx = -Math.sin(phase) * direction, hy = Math.cos(phase) * direction;
  return {
    eye: [ex, ey, hi[2] + 0.1 * extent],
    target: [ex + 0.1 * extent * hx, ey + 0.1 * extent * hy, 0.5 * (lo[2] + hi[2])],
    up: UP,
  };
}

export function circle(lo, hi, camera, t, secondsPerLap = 60) {
  const { extent, centre, terrain } = box(lo, hi);
  const phase = (2 * Math.PI * t) / secondsPerLap + camera * 0.5 * Math.PI;
  const radius = (terrain ? 0.45 : 1.5) * extent;
  return {
    eye: [centre[0] + radius * Math.cos(phase), centre[1] + radius * Math.sin(phase), terrain ? hi[2] + 0.15 * extent : centre[2]],
    target: centre,
    up: UP,
  };
}

export function rotate(lo, hi, camera, t, period = 8, degrees = 15) {
  const { extent, centre, terrain } = box(lo, hi);
  const around = camera * 0.5 * Math.PI - 0.5 * Math.PI;
  const distance = (terrain ? 0.6 : 1.5) * extent;
  const eye = [centre[0] + distance * Math.cos(around), centre[1] + distance * Math.sin(around), terrain ? hi[2] + 0.1 * extent : centre[2]];
  const swing = ((degrees * Math.PI) / 180) * Math.sin((2 * Math.PI * t) / period);
  const lx = centre[0] - eye[0], ly = centre[1] - eye[1], lz = centre[2] - eye[2];
  const c = Math.cos(swing), s = Math.sin(swing);
  return { eye, target: [eye[0] + c * lx - s * ly, eye[1] + s * lx + c * ly, eye[2] + lz], up: UP };
}

export function line(lo, hi, camera, t, seconds = 20) {
  const { extent, centre, terrain } = box(lo, hi);
  const phase = (t / seconds) % 2;
  const s = phase <= 1 ? phase : 2 - phase;
  const angle = camera * 0.5 * Math.PI, dx = Math.cos(angle), dy = Math.sin(angle);
  if (terrain) {
    const k = (s - 0.5) * 0.9 * extent;
    const eye = [centre[0] + k * dx, centre[1] + k * dy, hi[2] + 0.1 * extent];
    const forward = phase <= 1 ? 1 : -1;
    return { eye, target: [eye[0] + 0.1 * extent * forward * dx, eye[1] + 0.1 * extent * forward * dy, 0.5 * (lo[2] + hi[2])], up: UP };
  }
  const distance = (2 - 1.4 * s) * extent;
  return { eye: [centre[0] - distance * dx, centre[1] - distance * dy, centre[2]], target: centre, up: UP };
}

export const PATHS = { flyover, circle, rotate, line };
