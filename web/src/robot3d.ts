// A robot drawn from its URDF (three.js): the links' primitives and vendor meshes (fetched
// once each with the viewer's token, parsed by three.js's loaders; a mesh that cannot be had
// is counted, not drawn), its joints posed on demand, and the flight rules' worst pair of
// bodies highlighted. model3d.ts puts two of them (the arm and its commanded targets) in
// the satellite view.

import * as THREE from "three";
import { ColladaLoader } from "three/examples/jsm/loaders/ColladaLoader.js";
import { OBJLoader } from "three/examples/jsm/loaders/OBJLoader.js";
import { STLLoader } from "three/examples/jsm/loaders/STLLoader.js";
import { storedToken } from "./api";
import type { Vec3 } from "./flightrules";

interface UrdfJoint {
  name: string;
  type: string;
  parent: string;
  child: string;
  xyz: number[];
  rpy: number[];
  axis: number[];
}

const nums = (s: string | null | undefined, n: number, dflt = 0): number[] => {
  const parts = (s ?? "").trim().split(/\s+/).filter(Boolean).map(Number);
  return Array.from({ length: n }, (_, i) => parts[i] ?? dflt);
};

function originOf(el: Element | null): { xyz: number[]; rpy: number[] } {
  const o = el?.querySelector(":scope > origin");
  return { xyz: nums(o?.getAttribute("xyz"), 3), rpy: nums(o?.getAttribute("rpy"), 3) };
}

function place(obj: THREE.Object3D, xyz: number[], rpy: number[]): void {
  obj.position.set(xyz[0], xyz[1], xyz[2]);
  // URDF rpy: fixed-axis roll, pitch, yaw = Rz(yaw) Ry(pitch) Rx(roll): three's "ZYX".
  obj.quaternion.setFromEuler(new THREE.Euler(rpy[0], rpy[1], rpy[2], "ZYX"));
}

const meshFiles = new Map<string, Promise<THREE.Object3D>>();

/** The mesh file at ``url`` as three.js objects in its own frame (URDF: z up, metres), fetched
 * and parsed once; each caller clones it. */
function meshFile(url: string): Promise<THREE.Object3D> {
  let cached = meshFiles.get(url);
  if (!cached) {
    const headers: Record<string, string> = {};
    const token = storedToken();
    if (token) headers.Authorization = `Bearer ${token}`;
    cached = fetch(url, { headers }).then(async (r) => {
      if (!r.ok) throw new Error(`${url}: HTTP ${r.status}`);
      const ext = url.split("?")[0].split(".").pop()?.toLowerCase() ?? "";
      if (ext === "stl") {
        return new THREE.Mesh(new STLLoader().parse(await r.arrayBuffer()), new THREE.MeshStandardMaterial());
      }
      if (ext === "obj") return new OBJLoader().parse(await r.text());
      if (ext === "dae") {
        const scene = new ColladaLoader().parse(await r.text(), "")?.scene;
        if (!scene) throw new Error(`${url}: not a COLLADA document`);
        // The loader turns a Z_UP file to three's y up; a URDF's frames are z up already.
        scene.rotation.set(0, 0, 0);
        return scene;
      }
      throw new Error(`${url}: not a mesh the console draws (stl, dae, obj)`);
    });
    meshFiles.set(url, cached);
  }
  return cached;
}

/** What mesh visuals a robot asked for and what came of them. */
export interface MeshCounts {
  asked: number;
  loaded: number;
  failed: number;
}

function meshVisual(
  visual: Element,
  geometryEl: Element,
  opacity: number,
  counts: MeshCounts,
  done: () => void,
): THREE.Object3D {
  const holder = new THREE.Group();
  holder.userData.visual = true;
  const { xyz, rpy } = originOf(visual);
  place(holder, xyz, rpy);
  const [sx, sy, sz] = nums(geometryEl.getAttribute("scale"), 3, 1);
  holder.scale.set(sx, sy, sz);
  const colour = visual.querySelector("material > color")?.getAttribute("rgba");
  counts.asked += 1;
  meshFile(geometryEl.getAttribute("filename") ?? "")
    .then((file) => {
      const copy = file.clone(true);
      copy.traverse((o) => {
        if (!(o instanceof THREE.Mesh)) return;
        // One plain material per drawn mesh, so that highlighting and see-through act on it alone.
        const first = (Array.isArray(o.material) ? o.material[0] : o.material) as THREE.MeshStandardMaterial;
        const rgba = colour ? nums(colour, 4, 0.8) : null;
        o.material = new THREE.MeshStandardMaterial({
          color: rgba ? new THREE.Color(rgba[0], rgba[1], rgba[2]) : (first?.color?.clone() ?? new THREE.Color(0.8, 0.8, 0.85)),
          transparent: opacity < 1,
          opacity,
          metalness: 0.2,
          roughness: 0.6,
        });
      });
      holder.add(copy);
      counts.loaded += 1;
    })
    .catch(() => {
      counts.failed += 1;
    })
    .finally(done);
  return holder;
}

function visualMesh(
  visual: Element,
  opacity: number,
  counts: MeshCounts,
  done: () => void,
): THREE.Object3D | null {
  const geometryEl = visual.querySelector("geometry > *");
  if (!geometryEl) return null;
  let geometry: THREE.BufferGeometry;
  switch (geometryEl.tagName) {
    case "mesh":
      return meshVisual(visual, geometryEl, opacity, counts, done);
    case "box": {
      const [x, y, z] = nums(geometryEl.getAttribute("size"), 3, 0.1);
      geometry = new THREE.BoxGeometry(x, y, z);
      break;
    }
    case "cylinder": {
      const r = Number(geometryEl.getAttribute("radius") ?? 0.05);
      const l = Number(geometryEl.getAttribute("length") ?? 0.1);
      geometry = new THREE.CylinderGeometry(r, r, l, 20);
      geometry.rotateX(Math.PI / 2); // URDF cylinders lie along z, three's along y
      break;
    }
    case "sphere":
      geometry = new THREE.SphereGeometry(Number(geometryEl.getAttribute("radius") ?? 0.05), 20, 14);
      break;
    default:
      return null;
  }
  const rgba = nums(visual.querySelector("material > color")?.getAttribute("rgba"), 4, 0.8);
  const material = new THREE.MeshStandardMaterial({
    color: new THREE.Color(rgba[0], rgba[1], rgba[2]),
    transparent: opacity < 1,
    opacity,
    metalness: 0.2,
    roughness: 0.6,
  });
  const mesh = new THREE.Mesh(geometry, material);
  const { xyz, rpy } = originOf(visual);
  place(mesh, xyz, rpy);
  return mesh;
}

/** The highlight colours: an arm link of the worst pair, and equipment fixed to the base. */
const ARM_HIGHLIGHT = new THREE.Color(0xff2a2a);
const FIXED_HIGHLIGHT = new THREE.Color(0xffb020);

/** One copy of the robot: the base body and the revolute joints in URDF order. */
export class Robot {
  readonly root: THREE.Group;
  readonly joints: { pivot: THREE.Group; axis: THREE.Vector3 }[] = [];
  /** Every link's frame, by its URDF name. */
  readonly links = new Map<string, THREE.Group>();
  /** The root link (the base body): the frame the robot frame's points are drawn in. */
  readonly rootLink: THREE.Group;
  /** The links a joint moves (the arm), as opposed to the base and what is fixed on it. */
  readonly moving = new Set<string>();
  /** The robot frame's origin in the root link's frame: joint 1's origin (the robot frame
   * has the base's axes, so only this offset turns its points into the base frame). */
  readonly robotOrigin = new THREE.Vector3();
  /** The mesh files its visuals asked for, loaded and failed (counted as they arrive). */
  readonly meshes: MeshCounts = { asked: 0, loaded: 0, failed: 0 };

  constructor(doc: Document, opacity: number, withBase: boolean, changed: () => void = () => {}) {
    const links = this.links;
    for (const link of doc.querySelectorAll("robot > link")) {
      const g = new THREE.Group();
      g.name = link.getAttribute("name") ?? "";
      const isBase = g.name === "base_link";
      if (withBase || !isBase) {
        for (const visual of link.querySelectorAll(":scope > visual")) {
          const mesh = visualMesh(visual, isBase ? Math.min(opacity, 0.9) : opacity, this.meshes, changed);
          if (mesh) g.add(mesh);
        }
      }
      links.set(g.name, g);
    }
    const joints: UrdfJoint[] = [...doc.querySelectorAll("robot > joint")].map((j) => ({
      name: j.getAttribute("name") ?? "",
      type: j.getAttribute("type") ?? "fixed",
      parent: j.querySelector("parent")?.getAttribute("link") ?? "",
      child: j.querySelector("child")?.getAttribute("link") ?? "",
      ...originOf(j),
      axis: nums(j.querySelector("axis")?.getAttribute("xyz"), 3, 0),
    }));
    const children = new Set(joints.map((j) => j.child));
    let firstFrame: THREE.Group | null = null;
    for (const j of joints) {
      const parent = links.get(j.parent);
      const child = links.get(j.child);
      if (!parent || !child) continue;
      const frame = new THREE.Group();
      place(frame, j.xyz, j.rpy);
      const pivot = new THREE.Group();
      frame.add(pivot);
      pivot.add(child);
      parent.add(frame);
      if (j.type === "revolute" || j.type === "continuous") {
        this.joints.push({ pivot, axis: new THREE.Vector3(...j.axis).normalize() });
        firstFrame ??= frame;
      }
    }
    const rootName = [...links.keys()].find((n) => !children.has(n)) ?? "base_link";
    this.rootLink = links.get(rootName) ?? new THREE.Group();
    this.root = new THREE.Group();
    this.root.add(this.rootLink);
    for (const { pivot } of this.joints) {
      pivot.traverse((o) => {
        if (o instanceof THREE.Group && links.get(o.name) === o) this.moving.add(o.name);
      });
    }
    if (firstFrame) {
      // At the all-zero pose nothing before joint 1 moves: its origin is fixed on the base.
      this.root.updateMatrixWorld(true);
      this.rootLink.worldToLocal(firstFrame.getWorldPosition(this.robotOrigin));
    }
  }

  /** Colour the named links' own shapes (not their children's) and restore the others';
   * the names coloured (the root link never is). */
  colour(names: Set<string>): string[] {
    const coloured: string[] = [];
    for (const [name, link] of this.links) {
      const on = names.has(name) && link !== this.rootLink;
      // While a pair is shown the base body is see-through: the arm may be inside it.
      const seeThrough = names.size > 0 && link === this.rootLink;
      const shapes: THREE.Mesh[] = [];
      for (const child of link.children) {
        if (child instanceof THREE.Mesh) shapes.push(child);
        else if (child.userData.visual) child.traverse((o) => o instanceof THREE.Mesh && shapes.push(o));
      }
      for (const child of shapes) {
        const material = child.material as THREE.MeshStandardMaterial;
        type Saved = { color: THREE.Color; emissive: THREE.Color; opacity: number; transparent: boolean };
        const saved = child.userData.colour as Saved | undefined;
        if (on || seeThrough) {
          if (!saved) {
            child.userData.colour = {
              color: material.color.clone(), emissive: material.emissive.clone(),
              opacity: material.opacity, transparent: material.transparent,
            } satisfies Saved;
          }
          if (on) {
            const c = this.moving.has(name) ? ARM_HIGHLIGHT : FIXED_HIGHLIGHT;
            material.color.copy(c);
            material.emissive.copy(c).multiplyScalar(0.45);
          } else {
            material.transparent = true;
            material.opacity = Math.min(material.opacity, 0.35);
          }
          material.needsUpdate = true;
        } else if (saved) {
          material.color.copy(saved.color);
          material.emissive.copy(saved.emissive);
          material.opacity = saved.opacity;
          material.transparent = saved.transparent;
          delete child.userData.colour;
          material.needsUpdate = true;
        }
      }
      if (on) coloured.push(name);
    }
    return coloured;
  }

  /** A point of the robot frame (m) in the root link's frame. */
  fromRobotFrame(p: Vec3): THREE.Vector3 {
    return new THREE.Vector3(p[0], p[1], p[2]).add(this.robotOrigin);
  }

  setJoints(anglesRad: ArrayLike<number>): void {
    this.joints.forEach((j, i) => {
      const a = anglesRad[i];
      if (Number.isFinite(a)) j.pivot.quaternion.setFromAxisAngle(j.axis, a);
    });
  }
}
