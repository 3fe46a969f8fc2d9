// The result viewer: a GLB scene (three.js, vendored) with orbit and zoom, each top-level node (the
// "target" and the "source" of an alignment) listed with a visibility toggle and an optional tint. The same
// viewer previews an input file as the browser reads it, with the up the service will use. On a result the
// source can be moved, turned and scaled by hand (TransformControls' handles, about its box centre).
//
// Frames: the GLB's root is the target file frame (the target node is identity); a source matrix read or set
// here is the source node's, source file frame -> target file frame, as rows (the report's transform.matrix).
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
import { OBJLoader } from "three/addons/loaders/OBJLoader.js";
import { PLYLoader } from "three/addons/loaders/PLYLoader.js";
import { STLLoader } from "three/addons/loaders/STLLoader.js";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { TransformControls } from "three/addons/controls/TransformControls.js";

const BACKGROUND = 0xf0f2f5;
const TINTS = [0x3b82f6, 0xf97316, 0x22c55e, 0xa855f7, 0xeab308];

/** A similarity given as 4 rows (source file -> target file) as the report writes one: matrix, translation,
 * rotation as a quaternion (w, x, y, z) and the one scale. */
export function similarityParts(rows) {
  const position = new THREE.Vector3();
  const rotation = new THREE.Quaternion();
  const scale = new THREE.Vector3();
  new THREE.Matrix4().set(...rows.flat()).decompose(position, rotation, scale);
  return { matrix: rows, translation: position.toArray(), rotation_wxyz: [rotation.w, rotation.x, rotation.y, rotation.z],
           scale: scale.x };
}

export class Viewer {
  constructor(container) {
    this.container = container;
    // preserveDrawingBuffer: the canvas can be read back (a screenshot, the browser test's pixel check).
    this.renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    container.appendChild(this.renderer.domElement);
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(BACKGROUND);
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x8a8f99, 2.0));
    const sun = new THREE.DirectionalLight(0xffffff, 1.6);
    sun.position.set(1, 2, 1.5);
    this.scene.add(sun);
    this.camera = new THREE.PerspectiveCamera(40, 4 / 3, 0.01, 1000);
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.addEventListener("change", () => this.render());
    this.parts = [];
    this.model = null;
    this.pivot = null; // the handles' object: at the source's box centre, the source under it
    this.onAdjust = null; // called with the source's matrix (rows) whenever a handle moves it
    new ResizeObserver(() => this.resize()).observe(container);
  }

  resize() {
    const { clientWidth: w, clientHeight: h } = this.container;
    if (!w || !h) return;
    this.renderer.setSize(w, h, false);
    this.renderer.domElement.style.width = "100%";
    this.renderer.domElement.style.height = "100%";
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.render();
  }

  render() {
    this.renderer.render(this.scene, this.camera);
  }

  /** Show a GLB (an ArrayBuffer); returns its parts: [{name, object, tint}] in file order. */
  async show(buffer) {
    return this.showModel((await new GLTFLoader().parseAsync(buffer, "")).scene);
  }

  /** Show an uploaded mesh file as the browser reads it (an input preview): GLB, glTF with embedded buffers,
   * OBJ, PLY or STL by its extension; throws for others (an OBJ+MTL zip). */
  async showFile(file) {
    const ext = file.name.toLowerCase().split(".").pop();
    const plain = (geometry) => {
      if (!geometry.hasAttribute("normal")) geometry.computeVertexNormals();
      const material = new THREE.MeshStandardMaterial({ color: 0xb0b7c3, roughness: 0.8,
        vertexColors: geometry.hasAttribute("color") });
      return new THREE.Mesh(geometry, material);
    };
    if (ext === "glb" || ext === "gltf") return this.show(await file.arrayBuffer());
    if (ext === "obj") return this.showModel(new OBJLoader().parse(await file.text()));
    if (ext === "ply") return this.showModel(plain(new PLYLoader().parse(await file.arrayBuffer())));
    if (ext === "stl") return this.showModel(plain(new STLLoader().parse(await file.arrayBuffer())));
    throw new Error(`no 3D preview for .${ext} files in the browser`);
  }

  /** Draw the up (green) and the front (orange; dashed where it is a guess) a job will use, unit vectors in the
   * file frame, as arrows from the model's centre. */
  showAxes(up, front, trusted) {
    for (const arrow of this.arrows || []) this.scene.remove(arrow);
    this.arrows = [];
    if (!this.model) return;
    const box = new THREE.Box3().setFromObject(this.model);
    const length = box.getSize(new THREE.Vector3()).length() * 0.6;
    const centre = box.getCenter(new THREE.Vector3());
    for (const [vector, colour] of [[up, 0x16a34a], [front, trusted ? 0xea580c : 0xfdba74]]) {
      const arrow = new THREE.ArrowHelper(new THREE.Vector3(...vector).normalize(), centre, length, colour,
        length * 0.2, length * 0.1);
      this.arrows.push(arrow);
      this.scene.add(arrow);
    }
    this.render();
  }

  showModel(model) {
    this.handles?.detach();
    this.pivot = null;
    if (this.model) this.scene.remove(this.model);
    for (const arrow of this.arrows || []) this.scene.remove(arrow);
    this.arrows = [];
    this.model = model;
    this.scene.add(this.model);
    this.parts = this.model.children.map((object, i) => {
      const materials = new Map();
      object.traverse((o) => { if (o.isMesh) materials.set(o, o.material); });
      const tint = TINTS[i % TINTS.length];
      const tinted = new THREE.MeshStandardMaterial({ color: tint, roughness: 0.7 });
      return { name: object.name || `object ${i + 1}`, object, materials, tint, tinted };
    });
    this.frame();
    this.resize();
    return this.parts;
  }

  /** The handles' object on ``part`` (a result's source): a pivot at its box centre with the source under it,
   * its world placement kept. The handles stay hidden until ``setHandles`` picks a mode. */
  adjustable(part) {
    if (this.pivot) { // another part had the handles (one of several copies): it stays where it is
      this.model.attach(this.source);
      this.model.remove(this.pivot);
    }
    if (!this.handles) {
      this.handles = new TransformControls(this.camera, this.renderer.domElement);
      this.handles.addEventListener("change", () => this.render());
      this.handles.addEventListener("dragging-changed", (e) => { this.controls.enabled = !e.value; });
      this.handles.addEventListener("mouseDown", () => { this.scaleStart = this.pivot.scale.x; });
      this.handles.addEventListener("objectChange", () => this.handlesMoved());
      this.scene.add(this.handles.getHelper());
    }
    this.source = part.object;
    this.pivot = new THREE.Group();
    this.pivot.name = "handles";
    this.model.add(this.pivot);
    this.recentre();
    this.setHandles(this.mode || null);
  }

  /** "translate", "rotate", "scale", or null for none (the view only orbits). */
  setHandles(mode) {
    this.mode = mode;
    if (!this.pivot || !mode) {
      this.handles?.detach();
    } else {
      this.handles.attach(this.pivot);
      this.handles.setMode(mode);
    }
    this.render();
  }

  /** Scale stays one factor (a similarity: the service refuses uneven scales): the axis a handle changed since
   * the drag began (the others stay at the start, as TransformControls scales from it) sets all three. */
  handlesMoved() {
    if (this.mode === "scale") {
      const start = this.scaleStart;
      const { x, y, z } = this.pivot.scale;
      this.pivot.scale.setScalar([x, y, z].reduce((a, b) => (Math.abs(b - start) > Math.abs(a - start) ? b : a)));
    }
    if (this.onAdjust) this.onAdjust(this.sourceMatrix());
  }

  /** The source node's matrix now, source file -> target file, as 4 rows. */
  sourceMatrix() {
    this.model.updateMatrixWorld(true);
    const m = new THREE.Matrix4().copy(this.model.matrixWorld).invert().multiply(this.source.matrixWorld);
    const e = m.elements; // column-major
    return [0, 1, 2, 3].map((r) => [0, 1, 2, 3].map((c) => e[c * 4 + r]));
  }

  /** Put the source node at a matrix (4 rows, source file -> target file); the handles follow it. */
  placeSource(rows) {
    this.model.attach(this.source);
    new THREE.Matrix4().set(...rows.flat()).decompose(this.source.position, this.source.quaternion, this.source.scale);
    this.recentre();
    this.render();
  }

  /** The pivot back at the source's box centre, unturned and unscaled, with the source under it. */
  recentre() {
    this.model.attach(this.source);
    this.pivot.position.set(0, 0, 0);
    this.pivot.quaternion.identity();
    this.pivot.scale.setScalar(1);
    this.model.updateMatrixWorld(true);
    const centre = new THREE.Box3().setFromObject(this.source).getCenter(new THREE.Vector3());
    this.pivot.position.copy(this.model.worldToLocal(centre));
    this.pivot.updateMatrixWorld(true);
    this.pivot.attach(this.source);
  }

  /** The direction the camera looks (eye into the scene), target file frame: "push along view". */
  viewDirection() {
    const d = this.camera.getWorldDirection(new THREE.Vector3());
    d.transformDirection(new THREE.Matrix4().copy(this.model.matrixWorld).invert());
    return [d.x, d.y, d.z];
  }

  /** Put the whole scene in view from a three-quarter angle above it. */
  frame() {
    const box = new THREE.Box3().setFromObject(this.model);
    const sphere = box.getBoundingSphere(new THREE.Sphere());
    const radius = sphere.radius || 1;
    const distance = radius / Math.sin(THREE.MathUtils.degToRad(this.camera.fov / 2)) * 1.1;
    const direction = new THREE.Vector3(1, 0.8, 1.4).normalize();
    this.camera.position.copy(sphere.center).addScaledVector(direction, distance);
    this.camera.near = distance / 100;
    this.camera.far = distance * 100;
    this.camera.updateProjectionMatrix();
    this.controls.target.copy(sphere.center);
    this.controls.update();
  }

  setVisible(part, visible) {
    part.object.visible = visible;
    this.render();
  }

  /** A picture of the scene as the view shows it, ``part`` in its own flat colour and the others in their
   * materials (a scene's object list shows where each object is): a PNG data URL; the view is drawn back after. */
  thumbnail(part) {
    const shown = new Map();
    for (const p of this.parts) for (const mesh of p.materials.keys()) shown.set(mesh, mesh.material);
    for (const p of this.parts) {
      for (const [mesh, original] of p.materials) mesh.material = p === part ? part.tinted : original;
    }
    this.render();
    const url = this.renderer.domElement.toDataURL("image/png");
    for (const [mesh, material] of shown) mesh.material = material;
    this.render();
    return url;
  }

  /** Tinted: every part in its own flat colour (told apart at a glance); untinted: the file's materials. */
  setTinted(tinted) {
    for (const part of this.parts) {
      for (const [mesh, original] of part.materials) {
        mesh.material = tinted ? part.tinted : original;
      }
    }
    this.render();
  }
}
