// The 3D view: three.js scene, orbit controls, shapes with a per-pixel colour field (viridis +
// isolines in the fragment shader, or per-vertex colours), markers, paths and match lines.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { viridisBytes } from './colors.js';

const BACKGROUND = 0xf4f4f2;
const NEUTRAL = new THREE.Color(0.78, 0.74, 0.68);
const VIEW_DIRECTION = new THREE.Vector3(0.75, 0.35, 0.56).normalize(); // y-up three-quarter
const UP = new THREE.Vector3(0, 1, 0);
const PAIR_OFFSET = 1.15; // shapes are normalized to a unit bounding sphere

const MODE_NEUTRAL = 0;
const MODE_FIELD = 1;
const MODE_COLORS = 2;

const surfaceVertex = /* glsl */ `
attribute float dist;
attribute vec3 vcolor;
varying vec3 vNormalView;
varying float vDist;
varying vec3 vColor;
void main() {
  vNormalView = normalize(normalMatrix * normal);
  vDist = dist;
  vColor = vcolor;
  gl_Position = projectionMatrix * modelViewMatrix * vec4(position, 1.0);
}`;

const shading = /* glsl */ `
uniform int uMode;
uniform sampler2D uColormap;
uniform float uMax;
uniform float uStep;
uniform float uIsolines;
uniform vec3 uNeutral;
vec3 baseColor(float d, vec3 c) {
  if (uMode == 1) {
    float t = clamp(d / max(uMax, 1e-20), 0.0, 1.0);
    vec3 rgb = texture2D(uColormap, vec2((t * 255.0 + 0.5) / 256.0, 0.5)).rgb;
    if (uIsolines > 0.5 && uStep > 0.0) {
      float f = d / uStep;
      float w = max(fwidth(f), 1e-6);
      float e = abs(fract(f - 0.5) - 0.5);
      float line = 1.0 - smoothstep(0.5 * w, 1.5 * w, e);
      rgb = mix(rgb, rgb * 0.22, line * 0.9);
    }
    return rgb;
  }
  if (uMode == 2) return c;
  return uNeutral;
}
float lambert(vec3 n) {
  vec3 key = normalize(vec3(-0.35, 0.45, 0.55));
  float diffuse = 0.7 * max(dot(n, key), 0.0) + 0.3 * max(n.z, 0.0);
  return 0.32 + 0.68 * diffuse;
}`;

const surfaceFragment = /* glsl */ `
${shading}
varying vec3 vNormalView;
varying float vDist;
varying vec3 vColor;
void main() {
  vec3 n = normalize(vNormalView);
  if (!gl_FrontFacing) n = -n;
  gl_FragColor = vec4(baseColor(vDist, vColor) * lambert(n), 1.0);
}`;

const pointsVertex = /* glsl */ `
attribute float dist;
attribute vec3 vcolor;
uniform float uSize;
uniform float uPointScale;
varying float vDist;
varying vec3 vColor;
void main() {
  vDist = dist;
  vColor = vcolor;
  vec4 mv = modelViewMatrix * vec4(position, 1.0);
  gl_PointSize = max(2.0, uSize * uPointScale / -mv.z);
  gl_Position = projectionMatrix * mv;
}`;

const pointsFragment = /* glsl */ `
${shading}
varying float vDist;
varying vec3 vColor;
void main() {
  vec2 p = gl_PointCoord * 2.0 - 1.0;
  float r2 = dot(p, p);
  if (r2 > 1.0) discard;
  vec3 n = vec3(p.x, -p.y, sqrt(1.0 - r2));
  gl_FragColor = vec4(baseColor(vDist, vColor) * lambert(n), 1.0);
}`;

let colormapTexture = null;
function colormap() {
  if (!colormapTexture) {
    colormapTexture = new THREE.DataTexture(viridisBytes(), 256, 1, THREE.RGBAFormat);
    colormapTexture.magFilter = THREE.LinearFilter;
    colormapTexture.minFilter = THREE.LinearFilter;
    colormapTexture.needsUpdate = true;
  }
  return colormapTexture;
}

/** One shape in the scene: a mesh or a point cloud in its own units, normalized by a group. */
export class ShapeView {
  constructor(positions, index) {
    this.n = positions.length / 3;
    this.isMesh = Boolean(index && index.length);
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(positions, 3));
    geometry.setAttribute('dist', new THREE.BufferAttribute(new Float32Array(this.n), 1));
    geometry.setAttribute('vcolor', new THREE.BufferAttribute(new Float32Array(this.n * 3), 3));
    if (this.isMesh) {
      geometry.setIndex(new THREE.BufferAttribute(index, 1));
      geometry.computeVertexNormals();
    }
    geometry.computeBoundingSphere();
    this.geometry = geometry;
    const sphere = geometry.boundingSphere;
    this.center = sphere.center.clone();
    this.radius = sphere.radius > 0 ? sphere.radius : 1;
    this.uniforms = {
      uMode: { value: MODE_NEUTRAL },
      uColormap: { value: colormap() },
      uMax: { value: 1 },
      uStep: { value: 0 },
      uIsolines: { value: 1 },
      uNeutral: { value: NEUTRAL },
      uSize: { value: 1 },
      uPointScale: { value: 500 },
    };
    if (this.isMesh) {
      this.material = new THREE.ShaderMaterial({
        uniforms: this.uniforms,
        vertexShader: surfaceVertex,
        fragmentShader: surfaceFragment,
        side: THREE.DoubleSide,
      });
      this.object = new THREE.Mesh(geometry, this.material);
    } else {
      // spacing of a cloud: about 2.5 R / sqrt(N) between neighbours on a closed surface
      this.spacing = (2.5 * this.radius) / Math.sqrt(Math.max(this.n, 1));
      this.uniforms.uSize.value = (1.15 * this.spacing) / this.radius;
      this.material = new THREE.ShaderMaterial({
        uniforms: this.uniforms,
        vertexShader: pointsVertex,
        fragmentShader: pointsFragment,
      });
      this.object = new THREE.Points(geometry, this.material);
    }
    this.object.position.copy(this.center).multiplyScalar(-1);
    this.group = new THREE.Group();
    this.group.add(this.object);
    this.group.scale.setScalar(1 / this.radius);
    this.overlays = new THREE.Group();
    this.object.add(this.overlays);
    this.field = null;
  }

  vertexLocal(i) {
    const p = this.geometry.attributes.position;
    return new THREE.Vector3(p.getX(i), p.getY(i), p.getZ(i));
  }

  vertexWorld(i) {
    this.group.updateMatrixWorld(true);
    return this.object.localToWorld(this.vertexLocal(i));
  }

  setField(values, max, step) {
    const attribute = this.geometry.attributes.dist;
    attribute.array.set(values);
    attribute.needsUpdate = true;
    this.field = values;
    this.uniforms.uMax.value = max;
    this.uniforms.uStep.value = step;
    this.uniforms.uMode.value = MODE_FIELD;
  }

  setColors(colors) {
    const attribute = this.geometry.attributes.vcolor;
    attribute.array.set(colors);
    attribute.needsUpdate = true;
    this.uniforms.uMode.value = MODE_COLORS;
  }

  setNeutral() {
    this.uniforms.uMode.value = MODE_NEUTRAL;
    this.field = null;
  }

  setIsolines(on) {
    this.uniforms.uIsolines.value = on ? 1 : 0;
  }

  clearOverlays() {
    for (const child of [...this.overlays.children]) {
      this.overlays.remove(child);
      child.geometry?.dispose();
      child.material?.dispose();
    }
  }

  addMarker(i, color = 0xffffff) {
    const marker = new THREE.Mesh(
      new THREE.SphereGeometry(0.025 * this.radius, 20, 12),
      new THREE.MeshBasicMaterial({ color }),
    );
    marker.position.copy(this.vertexLocal(i));
    this.overlays.add(marker);
  }

  setPath(points) {
    const curve = new THREE.CatmullRomCurve3(points.map((p) => new THREE.Vector3(p[0], p[1], p[2])));
    const segments = Math.min(Math.max(points.length * 3, 16), 2000);
    const tube = new THREE.TubeGeometry(curve, segments, 0.007 * this.radius, 8, false);
    const mesh = new THREE.Mesh(tube, new THREE.MeshBasicMaterial({ color: 0xe5291f }));
    mesh.userData.kind = 'path';
    this.overlays.add(mesh);
  }

  dispose() {
    this.clearOverlays();
    this.geometry.dispose();
    this.material.dispose();
  }
}

/** The scene, camera, controls and picking. */
export class Viewer3D {
  constructor(canvas, { onPick } = {}) {
    this.canvas = canvas;
    this.onPick = onPick;
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    this.renderer.outputColorSpace = THREE.LinearSRGBColorSpace; // colours are display values
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(BACKGROUND);
    this.camera = new THREE.PerspectiveCamera(35, 1, 0.01, 100);
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.enableDamping = false;
    this.controls.addEventListener('change', () => this.requestRender());
    this.shapes = { x: null, y: null };
    this.pair = false;
    this.lines = new THREE.Group();
    this.scene.add(this.lines);
    this.raycaster = new THREE.Raycaster();
    this.pending = false;
    this.resize();
    new ResizeObserver(() => this.resize()).observe(canvas.parentElement);
    this.installPicking();
    this.installKeys();
    this.resetView();
  }

  resize() {
    const { clientWidth: w, clientHeight: h } = this.canvas;
    if (!w || !h) return;
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    const scale = this.renderer.getDrawingBufferSize(new THREE.Vector2()).y
      / (2 * Math.tan(THREE.MathUtils.degToRad(this.camera.fov) / 2));
    for (const shape of Object.values(this.shapes)) if (shape) shape.uniforms.uPointScale.value = scale;
    this.render();
  }

  requestRender() {
    if (this.pending) return;
    this.pending = true;
    requestAnimationFrame(() => {
      this.pending = false;
      this.render();
    });
  }

  render() {
    this.renderer.render(this.scene, this.camera);
  }

  setShape(slot, shape) {
    const old = this.shapes[slot];
    if (old) {
      this.scene.remove(old.group);
      old.dispose();
    }
    this.shapes[slot] = shape;
    if (shape) {
      this.scene.add(shape.group);
      this.resize();
    }
    this.clearLines();
    this.layout(this.pair);
  }

  swap() {
    [this.shapes.x, this.shapes.y] = [this.shapes.y, this.shapes.x];
    this.clearLines();
    this.layout(this.pair);
  }

  /** Place the shapes: X alone, or X and Y side by side across the default view. */
  layout(pair) {
    this.pair = Boolean(pair && this.shapes.x && this.shapes.y);
    const right = new THREE.Vector3().crossVectors(UP, VIEW_DIRECTION).normalize();
    const { x, y } = this.shapes;
    if (x) x.group.position.copy(this.pair ? right.clone().multiplyScalar(-PAIR_OFFSET) : new THREE.Vector3());
    if (y) {
      y.group.visible = this.pair;
      y.group.position.copy(right.clone().multiplyScalar(PAIR_OFFSET));
    }
    this.lines.visible = this.pair;
    this.resetView();
  }

  resetView() {
    const halfWidth = this.pair ? PAIR_OFFSET + 1 : 1;
    const tanHalf = Math.tan(THREE.MathUtils.degToRad(this.camera.fov) / 2);
    const distance = (this.pair ? 1.12 : 1.0) * Math.max(1 / tanHalf, halfWidth / (tanHalf * this.camera.aspect)) + 0.3;
    this.controls.target.set(0, 0, 0);
    this.camera.position.copy(VIEW_DIRECTION).multiplyScalar(distance);
    this.camera.up.copy(UP);
    this.camera.near = distance / 100;
    this.camera.far = distance * 10;
    this.camera.updateProjectionMatrix();
    this.controls.update();
    this.render();
  }

  clearLines() {
    for (const child of [...this.lines.children]) {
      this.lines.remove(child);
      child.geometry?.dispose();
      child.material?.dispose();
    }
  }

  addLine(from, to, color) {
    const geometry = new THREE.BufferGeometry().setFromPoints([from, to]);
    const line = new THREE.Line(geometry, new THREE.LineBasicMaterial({ color }));
    const dot = (p) => {
      const m = new THREE.Mesh(new THREE.SphereGeometry(0.025, 16, 10), new THREE.MeshBasicMaterial({ color }));
      m.position.copy(p);
      return m;
    };
    this.lines.add(line, dot(from), dot(to));
  }

  /** The slot and vertex under client position (x, y), or null. */
  pick(clientX, clientY) {
    const rect = this.canvas.getBoundingClientRect();
    const ndc = new THREE.Vector2(
      ((clientX - rect.left) / rect.width) * 2 - 1,
      -((clientY - rect.top) / rect.height) * 2 + 1,
    );
    this.raycaster.setFromCamera(ndc, this.camera);
    const candidates = [];
    for (const [slot, shape] of Object.entries(this.shapes)) {
      if (!shape || !shape.group.visible) continue;
      if (!shape.isMesh) this.raycaster.params.Points.threshold = (0.6 * shape.spacing) / shape.radius;
      for (const hit of this.raycaster.intersectObject(shape.object, false)) {
        candidates.push({ slot, shape, hit });
      }
    }
    if (!candidates.length) return null;
    candidates.sort((a, b) => a.hit.distance - b.hit.distance);
    const { slot, shape, hit } = candidates[0];
    if (!shape.isMesh) return { slot, vertex: hit.index };
    const local = shape.object.worldToLocal(hit.point.clone());
    let best = hit.face.a;
    let bestDistance = Infinity;
    for (const v of [hit.face.a, hit.face.b, hit.face.c]) {
      const d = shape.vertexLocal(v).distanceToSquared(local);
      if (d < bestDistance) {
        bestDistance = d;
        best = v;
      }
    }
    return { slot, vertex: best };
  }

  installPicking() {
    let down = null;
    this.canvas.addEventListener('pointerdown', (event) => {
      down = { x: event.clientX, y: event.clientY, button: event.button };
    });
    this.canvas.addEventListener('pointerup', (event) => {
      if (!down || down.button !== 0) return;
      const moved = Math.hypot(event.clientX - down.x, event.clientY - down.y);
      down = null;
      if (moved > 4) return;
      const picked = this.pick(event.clientX, event.clientY);
      if (picked && this.onPick) this.onPick({ ...picked, shift: event.shiftKey });
    });
  }

  installKeys() {
    this.canvas.addEventListener('keydown', (event) => {
      const step = 0.12;
      let handled = true;
      switch (event.key) {
        case 'ArrowLeft':
          if (event.shiftKey) this.controls.pan(40, 0); else this.controls.rotateLeft(step);
          break;
        case 'ArrowRight':
          if (event.shiftKey) this.controls.pan(-40, 0); else this.controls.rotateLeft(-step);
          break;
        case 'ArrowUp':
          if (event.shiftKey) this.controls.pan(0, 40); else this.controls.rotateUp(step);
          break;
        case 'ArrowDown':
          if (event.shiftKey) this.controls.pan(0, -40); else this.controls.rotateUp(-step);
          break;
        case '+':
        case '=':
          this.controls.dollyIn(1.15);
          break;
        case '-':
        case '_':
          this.controls.dollyOut(1.15);
          break;
        default:
          handled = false;
      }
      if (handled) {
        event.preventDefault();
        this.controls.update();
        this.render();
      }
    });
  }

  // ----------------------------------------------------------------- test and debug hooks

  /** Client (CSS pixel) position of a vertex of a slot's shape. */
  screenOf(slot, vertex) {
    const shape = this.shapes[slot];
    const p = shape.vertexWorld(vertex).project(this.camera);
    const rect = this.canvas.getBoundingClientRect();
    return { x: rect.left + ((p.x + 1) / 2) * rect.width, y: rect.top + ((1 - p.y) / 2) * rect.height };
  }

  /** Whether a vertex is the nearest surface along its line of sight, and not on the
   * silhouette (the pixels around it show the same shape). */
  isVisible(slot, vertex) {
    const { x, y } = this.screenOf(slot, vertex);
    const picked = this.pickPoint(x, y);
    if (!picked) return false;
    const world = this.shapes[slot].vertexWorld(vertex);
    if (picked.slot !== slot || picked.point.distanceTo(world) > 0.03) return false;
    for (const [dx, dy] of [[-3, 0], [3, 0], [0, -3], [0, 3]]) {
      if (this.pickPoint(x + dx, y + dy)?.slot !== slot) return false;
    }
    return true;
  }

  pickPoint(clientX, clientY) {
    const rect = this.canvas.getBoundingClientRect();
    const ndc = new THREE.Vector2(((clientX - rect.left) / rect.width) * 2 - 1, -((clientY - rect.top) / rect.height) * 2 + 1);
    this.raycaster.setFromCamera(ndc, this.camera);
    let best = null;
    for (const [slot, shape] of Object.entries(this.shapes)) {
      if (!shape || !shape.group.visible) continue;
      if (!shape.isMesh) this.raycaster.params.Points.threshold = (0.6 * shape.spacing) / shape.radius;
      const hit = this.raycaster.intersectObject(shape.object, false)[0];
      if (hit && (!best || hit.distance < best.distance)) best = { slot, point: hit.point, distance: hit.distance };
    }
    return best;
  }

  /** RGB bytes of the pixel at a client position (drawing buffer is preserved). */
  pixelAt(clientX, clientY) {
    const gl = this.renderer.getContext();
    const rect = this.canvas.getBoundingClientRect();
    const sx = gl.drawingBufferWidth / rect.width;
    const sy = gl.drawingBufferHeight / rect.height;
    const px = Math.floor((clientX - rect.left) * sx);
    const py = gl.drawingBufferHeight - 1 - Math.floor((clientY - rect.top) * sy);
    const out = new Uint8Array(4);
    gl.readPixels(px, py, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, out);
    return [out[0], out[1], out[2]];
  }

  /** Coverage and colour spread of the whole canvas. */
  canvasStats() {
    const gl = this.renderer.getContext();
    const w = gl.drawingBufferWidth;
    const h = gl.drawingBufferHeight;
    const data = new Uint8Array(w * h * 4);
    gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, data);
    const bg = new THREE.Color(BACKGROUND);
    const bgBytes = [bg.r, bg.g, bg.b].map((v) => Math.round(v * 255));
    let covered = 0;
    const colours = new Set();
    for (let i = 0; i < w * h; i++) {
      const r = data[i * 4];
      const g = data[i * 4 + 1];
      const b = data[i * 4 + 2];
      if (Math.abs(r - bgBytes[0]) + Math.abs(g - bgBytes[1]) + Math.abs(b - bgBytes[2]) > 6) {
        covered++;
        if (colours.size < 5000) colours.add((r >> 3) * 1024 + (g >> 3) * 32 + (b >> 3));
      }
    }
    return { width: w, height: h, covered: covered / (w * h), distinctColours: colours.size };
  }
}
