// The satellite and its arm in 3D (three.js), built from the model's URDF (boxes, cylinders
// and spheres; revolute and fixed joints). Frames: the scene's root is the orbit frame
// (x flight direction, z nadir) turned so nadir points down the screen; the base body is
// placed by quat_orbit_from_base. A second, translucent arm shows the commanded targets.
// Renders on demand (when a pose changes or the camera moves), never in a busy loop.
// The flight rules' worst pair of bodies can be highlighted: its arm link coloured, a
// segment between the two nearest points, labelled with the bodies and their distance.
// A vendor robot's <mesh> visuals (STL, DAE, OBJ, served by GET /api/robots/{name}/meshes/...)
// are fetched once each with the viewer's token and parsed by three.js's own loaders; the
// URDF draws no primitive where it has a mesh. A mesh that cannot be had is counted, not drawn.

import * as THREE from "three";
import { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";
import { storedToken } from "./api";
import type { WorstPair } from "./flightrules";

import { Robot } from "./robot3d";

export class SatelliteView {
  private renderer: THREE.WebGLRenderer;
  private scene = new THREE.Scene();
  private camera: THREE.PerspectiveCamera;
  private controls: OrbitControls;
  private orbit = new THREE.Group(); // the orbit frame
  private body = new THREE.Group(); // the base body frame
  private robot: Robot | null = null;
  private ghost: Robot | null = null;
  private pending = false;
  /** The worst pair's segment (in the root link's frame) and its label, when highlighted. */
  private pair: { line: THREE.Group; mid: THREE.Vector3 } | null = null;
  private readonly pairLabel: HTMLElement;
  readonly el: HTMLElement;

  constructor(parent: HTMLElement) {
    this.el = document.createElement("div");
    this.el.className = "view3d";
    this.el.dataset.test = "view3d";
    parent.appendChild(this.el);
    this.renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(devicePixelRatio);
    this.renderer.setClearColor(0x0d1017);
    this.el.appendChild(this.renderer.domElement);
    this.pairLabel = document.createElement("div");
    this.pairLabel.className = "pair-label";
    this.pairLabel.dataset.test = "worst-pair-label";
    this.pairLabel.hidden = true;
    this.el.appendChild(this.pairLabel);
    this.camera = new THREE.PerspectiveCamera(40, 1, 0.05, 100);
    this.camera.position.set(5.5, 2.5, 5.5);
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.target.set(0, 0.3, 0);
    this.controls.addEventListener("change", () => this.request());
    this.scene.add(new THREE.AmbientLight(0xffffff, 0.55));
    const sun = new THREE.DirectionalLight(0xffffff, 1.6);
    sun.position.set(4, 6, 3);
    this.scene.add(sun);
    // Orbit frame (x flight, z nadir) -> screen (y up): nadir points down.
    this.orbit.rotation.x = Math.PI / 2;
    this.orbit.add(new THREE.AxesHelper(0.8));
    this.orbit.add(this.body);
    this.scene.add(this.orbit);
    new ResizeObserver(() => this.resize()).observe(this.el);
    this.resize();
  }

  /** Build from URDF text; false when it cannot be read. */
  load(urdf: string): boolean {
    const doc = new DOMParser().parseFromString(urdf, "application/xml");
    if (doc.querySelector("parsererror") || !doc.querySelector("robot")) return false;
    const robot = new Robot(doc, 1, true, () => {
      // What came of the meshes, for the tests and the operator: asked, loaded, failed.
      this.el.dataset.meshesLoaded = String(robot.meshes.loaded);
      this.el.dataset.meshesFailed = String(robot.meshes.failed);
      this.request();
    });
    this.robot = robot;
    this.ghost = new Robot(doc, 0.3, false, () => this.request());
    this.body.add(this.robot.root, this.ghost.root);
    // What is drawn, for the tests: the URDF's robot and its moving joints.
    this.el.dataset.robot = doc.querySelector("robot")?.getAttribute("name") ?? "";
    this.el.dataset.joints = String(this.robot.joints.length);
    this.el.dataset.meshes = String(robot.meshes.asked);
    this.el.dataset.meshesLoaded = String(robot.meshes.loaded);
    this.el.dataset.meshesFailed = String(robot.meshes.failed);
    this.request();
    return true;
  }

  /** Measured joints (rad), targets (rad, or null to hide), quat_orbit_from_base (x, y, z, w). */
  setPose(joints: ArrayLike<number>, targets: ArrayLike<number> | null, quat: ArrayLike<number> | null): void {
    this.robot?.setJoints(joints);
    if (this.ghost) {
      this.ghost.root.visible = targets !== null;
      if (targets) this.ghost.setJoints(targets);
    }
    if (quat && [0, 1, 2, 3].every((i) => Number.isFinite(quat[i]))) {
      this.body.quaternion.set(quat[0], quat[1], quat[2], quat[3]).normalize();
    }
    this.request();
  }

  /** Highlight the flight rules' worst pair of bodies (null: none): the named links
   * coloured (the arm's red, equipment on the base amber; the base body itself is left as
   * it is, the segment shows where), a segment between the two nearest points (robot frame,
   * drawn in the base frame) over everything, and a label with the bodies and the distance.
   * The caller poses the arm at the pair's moment (``pair.t_s``) first. */
  showWorstPair(pair: WorstPair | null): void {
    const robot = this.robot;
    if (this.pair) {
      this.pair.line.removeFromParent();
      for (const o of this.pair.line.children) {
        if (o instanceof THREE.Mesh || o instanceof THREE.Line) {
          o.geometry.dispose();
          (o.material as THREE.Material).dispose();
        }
      }
      this.pair = null;
    }
    robot?.colour(new Set());
    this.pairLabel.hidden = true;
    delete this.el.dataset.highlight;
    delete this.el.dataset.highlightColoured;
    delete this.el.dataset.pairBaseM;
    delete this.el.dataset.pairBodiesBaseM;
    if (!robot || !pair) {
      this.request();
      return;
    }
    const coloured = robot.colour(new Set(pair.bodies));
    const a = robot.fromRobotFrame(pair.points_robot_m[0]);
    const b = robot.fromRobotFrame(pair.points_robot_m[1]);
    const colour = pair.failed ? 0xff2a2a : 0xffd54f;
    const group = new THREE.Group();
    const overAll = (m: THREE.Material): THREE.Material => {
      m.depthTest = false; // seen through the base box the hand is in
      m.transparent = true;
      return m;
    };
    const line = new THREE.Line(
      new THREE.BufferGeometry().setFromPoints([a, b]),
      overAll(new THREE.LineBasicMaterial({ color: colour })),
    );
    group.add(line);
    for (const p of [a, b]) {
      const dot = new THREE.Mesh(new THREE.SphereGeometry(0.025, 12, 8), overAll(new THREE.MeshBasicMaterial({ color: colour })));
      dot.position.copy(p);
      group.add(dot);
    }
    group.renderOrder = 999;
    group.traverse((o) => (o.renderOrder = 999));
    robot.rootLink.add(group);
    this.pair = { line: group, mid: a.clone().add(b).multiplyScalar(0.5) };
    const d = pair.distance_m;
    this.pairLabel.textContent =
      `${pair.bodies[0]} – ${pair.bodies[1]}: ${d < 0 ? `${(-d).toFixed(3)} m inside` : `${d.toFixed(3)} m`}` +
      ` (least ${pair.limit_m} m) at t = ${pair.t_s.toFixed(2)} s`;
    this.pairLabel.classList.toggle("fail", pair.failed);
    this.pairLabel.hidden = false;
    // What is drawn, for the tests: the pair, the links coloured, the segment's ends (base frame).
    this.el.dataset.highlight = pair.bodies.join(",");
    this.el.dataset.highlightColoured = coloured.join(",");
    this.el.dataset.pairBaseM = JSON.stringify([a.toArray(), b.toArray()]);
    this.el.dataset.pairBodiesBaseM = JSON.stringify(pair.bodies.map((n) => this.linkPosition(n)));
    this.request();
  }

  /** A link's origin in the root link's frame (m), as drawn now; null for an unknown link. */
  linkPosition(name: string): number[] | null {
    const robot = this.robot;
    const link = robot?.links.get(name);
    if (!robot || !link) return null;
    this.scene.updateMatrixWorld(true);
    return robot.rootLink.worldToLocal(link.getWorldPosition(new THREE.Vector3())).toArray();
  }

  /** Keep the label over the segment's middle (after each render: the camera may move). */
  private placeLabel(): void {
    if (!this.pair) return;
    const p = this.pair.line.localToWorld(this.pair.mid.clone()).project(this.camera);
    const w = this.renderer.domElement.clientWidth;
    const hgt = this.renderer.domElement.clientHeight;
    const inFront = p.z < 1;
    this.pairLabel.style.left = `${Math.round(((p.x + 1) / 2) * w)}px`;
    this.pairLabel.style.top = `${Math.round(((1 - p.y) / 2) * hgt)}px`;
    this.pairLabel.style.visibility = inFront ? "visible" : "hidden";
  }

  private resize(): void {
    const w = this.el.clientWidth || 300;
    const h = this.el.clientHeight || 260;
    this.renderer.setSize(w, h);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.request();
  }

  private request(): void {
    if (this.pending) return;
    this.pending = true;
    requestAnimationFrame(() => {
      this.pending = false;
      this.renderer.render(this.scene, this.camera);
      this.placeLabel();
    });
  }

  dispose(): void {
    this.controls.dispose();
    this.renderer.dispose();
  }
}

/** The robot a pass or plan is for, as its plan document names it. */
export interface RobotRef {
  name: string | null;
  hash: string | null;
}

export interface UrdfResult {
  urdf: string | null;
  /** Why there is none, for the operator. */
  reason: string;
  /** Where it came from. */
  url: string | null;
}

const ETS7 = "ets7";
const urdfTexts = new Map<string, Promise<UrdfResult>>();

function fetchText(url: string, what: string): Promise<UrdfResult> {
  let cached = urdfTexts.get(url);
  if (!cached) {
    const headers: Record<string, string> = {};
    const token = storedToken();
    if (token) headers.Authorization = `Bearer ${token}`;
    cached = fetch(url, { headers })
      .then(async (r): Promise<UrdfResult> => {
        if (r.ok) return { urdf: await r.text(), reason: "", url };
        let message = `HTTP ${r.status}`;
        try {
          message = ((await r.json()) as { detail?: string }).detail ?? message; // RFC 9457
        } catch {
          // not the server's error shape
        }
        return { urdf: null, reason: `${what}: ${message}`, url };
      })
      .catch((e: Error): UrdfResult => ({ urdf: null, reason: `${what}: ${e.message}`, url }));
    urdfTexts.set(url, cached);
  }
  return cached;
}

/** The URDF of ``robot`` (the robot of a pass's plan): ``GET /api/robots/by-hash/{hash}/urdf``
 * when the server offers it. ETS-VII's (no robot named, or the server lists no robots):
 * ``GET /api/model/urdf``, else the copy the setup script exports next to the console
 * (``/model/ets7.urdf``). Another robot on a server without robots: none, with the reason
 * (never ETS-VII drawn for another robot). */
export function fetchUrdf(paths: Set<string>, robot: RobotRef | null = null): Promise<UrdfResult> {
  const name = robot?.name ?? ETS7;
  if (robot?.hash && paths.has("/api/robots/by-hash/{robot_hash}/urdf")) {
    return fetchText(`/api/robots/by-hash/${encodeURIComponent(robot.hash)}/urdf`, `robot ${name}`);
  }
  if (name !== ETS7) {
    return Promise.resolve({
      urdf: null,
      reason: `this server does not serve robot ${name}'s URDF`,
      url: null,
    });
  }
  const url = paths.has("/api/model/urdf") ? "/api/model/urdf" : "/model/ets7.urdf";
  return fetchText(url, "ETS-VII's model");
}
