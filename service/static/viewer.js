// The result viewer: a GLB scene (three.js, vendored) with orbit and zoom, each top-level node (the
// "target" and the "source" of an alignment) listed with a visibility toggle and an optional tint.
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";

const BACKGROUND = 0xf0f2f5;
const TINTS = [0x3b82f6, 0xf97316, 0x22c55e, 0xa855f7, 0xeab308];

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
    const gltf = await new GLTFLoader().parseAsync(buffer, "");
    if (this.model) this.scene.remove(this.model);
    this.model = gltf.scene;
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
