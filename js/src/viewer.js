// The report's interactive splat viewer: three.js + Spark (both MIT), bundled by build.mjs into one
// self-contained script (go_pipeline/_resources/viewer/viewer.min.js) that report.html inlines.
//
// The page holds <script type="application/json" id="go-viewer-data"> with {model: base64 .spz, cameras:
// {train: [...], test: [...]}, background: [r, g, b]} (cameras in go-pipeline's convention: OpenCV,
// world-to-camera R | t, pixel centres at +0.5, fx fy cx cy in pixels of width x height), optionally
// mesh: base64 gzip of the mesh step's model_mesh.ply (world frame, vertex colours), and a
// <div id="go-viewer">. window.goViewer.ready resolves once the model is loaded and drawn;
// goViewer.showView(kind, index, width, height) puts the camera exactly on a scene camera;
// goViewer.showTab("mesh" | "splats") shows the mesh (loaded on first use) or the splats from the same camera.
import { SparkRenderer, SplatFileType, SplatMesh } from "@sparkjsdev/spark";
import * as THREE from "three";
import { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";
import { PLYLoader } from "three/examples/jsm/loaders/PLYLoader.js";

const NEAR = 0.01; // go-pipeline's rasterizer: near_plane 0.01
const FAR = 1000.0;

function b64ToBytes(b64) {
  const bin = atob(b64);
  const out = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) out[i] = bin.charCodeAt(i);
  return out;
}

// OpenCV intrinsics -> a WebGL projection: NDC x = 2u/W - 1, NDC y = 1 - 2v/H, for u, v in pixels.
function projection(cam) {
  const { fx, fy, cx, cy, width: w, height: h } = cam;
  const m = new THREE.Matrix4();
  m.set(
    (2 * fx) / w, 0, 1 - (2 * cx) / w, 0,
    0, (2 * fy) / h, (2 * cy) / h - 1, 0,
    0, 0, -(FAR + NEAR) / (FAR - NEAR), (-2 * FAR * NEAR) / (FAR - NEAR),
    0, 0, -1, 0,
  );
  return m;
}

// OpenCV world-to-camera (R, t) -> the three.js camera's world matrix (camera axes x right, y up, z back).
function cameraToWorld(cam) {
  const [r, t] = [cam.R, cam.t];
  const w2c = new THREE.Matrix4().set(
    r[0][0], r[0][1], r[0][2], t[0],
    r[1][0], r[1][1], r[1][2], t[1],
    r[2][0], r[2][1], r[2][2], t[2],
    0, 0, 0, 1,
  );
  const flip = new THREE.Matrix4().makeScale(1, -1, -1);
  return w2c.invert().multiply(flip);
}

async function gunzip(bytes) {
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("gzip"));
  return new Response(stream).arrayBuffer();
}

// The mesh step's model_mesh.ply (world frame, sRGB vertex colours: PLYLoader turns them linear) as a
// three.js mesh with two materials: the vertex colours as they are (unlit) and the same colours shaded
// by a light at the camera, which shows the shape.
async function loadSurface(b64) {
  const geometry = new PLYLoader().parse(await gunzip(b64ToBytes(b64)));
  geometry.computeVertexNormals();
  const materials = {
    colours: new THREE.MeshBasicMaterial({ vertexColors: true, side: THREE.DoubleSide }),
    shaded: new THREE.MeshLambertMaterial({ vertexColors: true, side: THREE.DoubleSide }),
  };
  return { mesh: new THREE.Mesh(geometry, materials.colours), materials, faces: geometry.index.count / 3 };
}

function frameSleep(n) {
  return new Promise((resolve) => {
    const step = (k) => (k <= 0 ? resolve() : requestAnimationFrame(() => step(k - 1)));
    step(n);
  });
}

class Viewer {
  constructor(root, data) {
    this.data = data;
    this.root = root;
    const first = data.cameras.train[0] || data.cameras.test[0];
    this.aspect = first.width / first.height;
    this.canvas = document.createElement("canvas");
    this.canvas.className = "go-viewer-canvas";
    root.querySelector(".go-viewer-stage").appendChild(this.canvas);
    this.renderer = new THREE.WebGLRenderer({ canvas: this.canvas, antialias: false, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(1);
    this.renderer.setClearColor(new THREE.Color(...data.background), 1);
    this.scene = new THREE.Scene();
    this.splatScene = this.scene;
    // the rasterizer's conventions: 3 sigma extent, 0.3 px² dilation without opacity compensation
    this.spark = new SparkRenderer({
      renderer: this.renderer,
      maxStdDev: 3.0,
      preBlurAmount: 0.3,
      blurAmount: 0.0,
      minAlpha: 1.0 / 255.0,
      sortRadial: false,
      clipXY: 1.4,
    });
    this.scene.add(this.spark);
    this.camera = new THREE.PerspectiveCamera(50, this.aspect, NEAR, FAR);
    this.camera.up.copy(this.upVector());
    this.controls = new OrbitControls(this.camera, this.canvas);
    this.controls.addEventListener("change", () => this.draw());
    this.resize(first.width, first.height);
    this.ready = this.load();
  }

  // the mean "up" (-y of OpenCV) of the training cameras: orbiting keeps it up
  upVector() {
    const up = new THREE.Vector3();
    for (const cam of this.data.cameras.train) up.add(new THREE.Vector3(-cam.R[1][0], -cam.R[1][1], -cam.R[1][2]));
    return up.lengthSq() > 0 ? up.normalize() : new THREE.Vector3(0, 1, 0);
  }

  async load() {
    this.mesh = new SplatMesh({ fileBytes: b64ToBytes(this.data.model), fileType: SplatFileType.SPZ });
    await this.mesh.initialized;
    this.mesh.quaternion.set(1, 0, 0, 0); // .spz holds RUB: turned 180 degrees about x back to OpenCV world
    this.splatScene.add(this.mesh); // the splats' scene, even if the mesh tab opened first
    this.center = new THREE.Vector3(...this.data.center);
    const kind = this.data.cameras.test.length ? "test" : "train";
    await this.showView(kind, 0);
    this.loop();
    return this;
  }

  // the mesh's own scene (ambient light + a light from the camera towards the orbit target, for "shaded")
  async meshScene() {
    if (!this.surfaceScene) {
      this.surfaceScene = (async () => {
        const surface = await loadSurface(this.data.mesh);
        const scene = new THREE.Scene();
        this.headlight = new THREE.DirectionalLight(0xffffff, 2.2);
        scene.add(surface.mesh, new THREE.AmbientLight(0xffffff, 0.35), this.headlight, this.headlight.target);
        this.surface = surface;
        return scene;
      })();
    }
    return this.surfaceScene;
  }

  // Show "mesh" (the mesh step's surface; "shaded" as a variant) or "splats", from the current camera.
  async showTab(tab, shaded = false) {
    if (tab === "mesh" && !this.data.mesh) throw new Error("this report has no mesh");
    this.scene = tab === "mesh" ? await this.meshScene() : this.splatScene;
    if (tab === "mesh") this.surface.mesh.material = this.surface.materials[shaded ? "shaded" : "colours"];
    this.tab = tab;
    this.root.querySelectorAll(".go-viewer-tabs button").forEach((b) => {
      b.classList.toggle("go-active", b.dataset.tab === (tab === "mesh" && shaded ? "shaded" : tab));
    });
    this.draw();
    await frameSleep(2);
    return tab;
  }

  resize(width, height) {
    this.renderer.setSize(width, height, false);
    this.canvas.style.width = `${width}px`;
    this.canvas.style.height = `${height}px`;
  }

  draw() {
    if (this.activeCamera) this.camera.projectionMatrix.copy(projection(this.activeCamera));
    this.camera.projectionMatrixInverse.copy(this.camera.projectionMatrix).invert();
    if (this.headlight) {
      this.headlight.position.copy(this.camera.position);
      this.headlight.target.position.copy(this.controls.target);
    }
    this.renderer.render(this.scene, this.camera);
  }

  loop() {
    const tick = () => {
      this.draw();
      requestAnimationFrame(tick);
    };
    requestAnimationFrame(tick);
  }

  // Put the camera on scene camera `index` of `kind` (train / test), drawing at width x height pixels
  // (default: the camera's own size, scaled to fit the page). Resolves once Spark has re-sorted.
  async showView(kind, index, width, height) {
    const cam = this.data.cameras[kind][index];
    // on the page: as wide as the report allows (at most 800 px); same aspect, so the same view
    const scale = width ? 1 : Math.min(800, this.root.clientWidth || cam.width) / cam.width;
    this.resize(width || Math.round(cam.width * scale), height || Math.round(cam.height * scale));
    this.activeCamera = cam;
    const world = cameraToWorld(cam);
    world.decompose(this.camera.position, this.camera.quaternion, this.camera.scale);
    this.camera.updateMatrixWorld(true);
    const forward = new THREE.Vector3(0, 0, -1).applyQuaternion(this.camera.quaternion);
    const depth = Math.max(this.center.clone().sub(this.camera.position).dot(forward), NEAR * 10);
    this.controls.target.copy(this.camera.position).addScaledVector(forward, depth);
    this.label(`${kind} camera ${cam.name}${this.tab === "mesh" ? `, mesh (${this.surface.faces} faces)` : ""}`);
    this.draw();
    await frameSleep(4);
    await new Promise((resolve) => setTimeout(resolve, 300));
    await frameSleep(4);
    const rect = this.canvas.getBoundingClientRect();
    return { x: rect.left + window.scrollX, y: rect.top + window.scrollY, width: rect.width, height: rect.height };
  }

  label(text) {
    const el = this.root.querySelector(".go-viewer-label");
    if (el) el.textContent = text;
  }
}

function buttons(root, viewer) {
  const bar = root.querySelector(".go-viewer-buttons");
  for (const kind of ["train", "test"]) {
    viewer.data.cameras[kind].forEach((cam, i) => {
      const b = document.createElement("button");
      b.textContent = `${kind} ${cam.name}`;
      b.addEventListener("click", () => viewer.showView(kind, i));
      bar.appendChild(b);
    });
  }
}

function tabs(root, viewer) {
  root.querySelectorAll(".go-viewer-tabs button").forEach((b) => {
    const [tab, shaded] = b.dataset.tab === "shaded" ? ["mesh", true] : [b.dataset.tab, false];
    b.addEventListener("click", () => viewer.showTab(tab, shaded).catch((err) => viewer.label(`${err}`)));
  });
}

function start() {
  const root = document.getElementById("go-viewer");
  const holder = document.getElementById("go-viewer-data");
  if (!root || !holder) return;
  const viewer = new Viewer(root, JSON.parse(holder.textContent));
  buttons(root, viewer);
  tabs(root, viewer);
  window.goViewer = viewer;
  viewer.ready.catch((err) => viewer.label(`viewer error: ${err}`));
}

if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", start);
else start();
