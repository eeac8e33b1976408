// mocapdb view: a take (or a live stream) as the engine wrote it: the image with the skeletons
// re-projected over it, a 3D view on the floor, a timeline. Data: data_specs/viewer.md.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/OrbitControls.js';

const CHUNK = 60;            // frames fetched per request
const VIDEO_AHEAD = 4;       // video frames fetched ahead while playing
const EVERYWHERE = new THREE.Sphere(new THREE.Vector3(), 1e4);   // a fixed bound: never computed from NaN
const LABEL_HEIGHT = 0.024;  // 3D labels: a share of the view's height
const INPUT_COLOUR = '#969696';
const HAND_COLOURS = ['#00e5ff', '#ff3df5'];   // the right hand's, the left's (image and 3D): unlike tracks 0-2
const FACE_COLOUR = '#ffffff';
const FACE_M = 0.3;          // the face's direction: a line this long (metres) from the head
const HAND_M = 0.12;         // each hand's direction: from the wrist
const $ = (id) => document.getElementById(id);

// ---------------------------------------------------------------- the 3D view

function textSprite(text, colour) {
  const canvas = document.createElement('canvas');
  const ctx = canvas.getContext('2d');
  ctx.font = '600 40px system-ui, sans-serif';
  canvas.width = Math.ceil(ctx.measureText(text).width) + 16;
  canvas.height = 56;
  ctx.font = '600 40px system-ui, sans-serif';
  ctx.fillStyle = 'rgba(0, 0, 0, 0.55)';
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  ctx.fillStyle = colour;
  ctx.fillText(text, 8, 42);
  const texture = new THREE.CanvasTexture(canvas);
  texture.colorSpace = THREE.SRGBColorSpace;
  const material = new THREE.SpriteMaterial({ map: texture, depthTest: false, sizeAttenuation: false });
  const sprite = new THREE.Sprite(material);   // the same size on the screen, near or far
  sprite.scale.set(LABEL_HEIGHT * canvas.width / canvas.height, LABEL_HEIGHT, 1);
  sprite.center.set(0.5, 0);
  return sprite;
}

// remove an object from its parent and free its GPU buffers and textures
function dispose(object) {
  object.removeFromParent();
  object.geometry?.dispose();
  object.material?.map?.dispose();
  object.material?.dispose();
}

class Scene3D {
  constructor(element, skeleton) {
    this.skeleton = skeleton;
    this.renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(window.devicePixelRatio);
    element.appendChild(this.renderer.domElement);
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color('#1c1e20');
    this.camera = new THREE.PerspectiveCamera(45, 1, 0.05, 500);
    this.camera.position.set(4, 3, 6);
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.addEventListener('change', () => this.render());
    this.people = new Map();   // track → {group, lines, points, ends, label}
    this.endJoints = ['head', 'r_wrist', 'l_wrist'].map((name) => skeleton.joints.indexOf(name));
    this.cameras = new THREE.Group();
    this.scene.add(this.cameras);
    this.setGrid(10, 0);
    new ResizeObserver(() => this.resize(element)).observe(element);
    this.resize(element);
  }

  resize(element) {
    const w = Math.max(1, element.clientWidth), h = Math.max(1, element.clientHeight);
    this.renderer.setSize(w, h);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.render();
  }

  render() { this.renderer.render(this.scene, this.camera); }

  setGrid(size, y) {
    if (this.grid && this.grid.userData.size === size && Math.abs(this.grid.position.y - y) < 0.01) return;
    if (this.grid) dispose(this.grid);
    const cells = Math.max(2, Math.round(size / 0.5));
    this.grid = new THREE.GridHelper(cells * 0.5, cells, '#5a6066', '#34383c');
    this.grid.position.y = y;
    this.grid.userData.size = size;
    this.scene.add(this.grid);
  }

  // a camera: its frustum (fov: tangents of half its field of view), a line down to the floor, a label
  setCameras(cameras, floorY) {
    const key = JSON.stringify([cameras, floorY], (k, v) => (typeof v === 'number' ? Math.round(v * 100) : v));
    if (key === this.camerasKey) return;
    this.camerasKey = key;
    for (const child of [...this.cameras.children]) dispose(child);
    for (const c of cameras) {
      const p = new THREE.Vector3(...c.position);
      const [right, down, forward] = c.axes.map((a) => new THREE.Vector3(...a));
      const [fx, fy] = c.fov || [0.5, 0.5];
      const depth = 0.35;
      const corner = (sx, sy) => p.clone().addScaledVector(forward, depth)
        .addScaledVector(right, sx * fx * depth).addScaledVector(down, sy * fy * depth);
      const k = [corner(-1, -1), corner(1, -1), corner(1, 1), corner(-1, 1)];
      const points = [p, k[0], p, k[1], p, k[2], p, k[3], k[0], k[1], k[1], k[2], k[2], k[3], k[3], k[0],
        p, new THREE.Vector3(p.x, floorY, p.z)];
      const geometry = new THREE.BufferGeometry().setFromPoints(points);
      this.cameras.add(new THREE.LineSegments(geometry, new THREE.LineBasicMaterial({ color: '#e8e8e8' })));
      if (!c.label) continue;   // a turning camera's frustums along its path: the last one is labelled
      const label = textSprite(c.label, '#e8e8e8');
      label.position.copy(p).addScaledVector(down, -0.15);
      this.cameras.add(label);
    }
  }

  person(track, colour, text) {
    let person = this.people.get(track);
    if (!person) {
      const material = { color: colour };
      const n = this.skeleton.lines.length * 2;
      const lines = new THREE.LineSegments(new THREE.BufferGeometry(), new THREE.LineBasicMaterial(material));
      lines.geometry.setAttribute('position', new THREE.BufferAttribute(new Float32Array(n * 3), 3));
      const points = new THREE.Points(new THREE.BufferGeometry(), new THREE.PointsMaterial({ ...material, size: 0.05 }));
      const joints = this.skeleton.joints.length;
      points.geometry.setAttribute('position', new THREE.BufferAttribute(new Float32Array(joints * 3), 3));
      const ends = this.endLines();
      for (const o of [lines, points, ends]) o.geometry.boundingSphere = EVERYWHERE;   // unknown joints are NaN
      const group = new THREE.Group();
      group.add(lines, points, ends);
      person = { group, lines, points, ends, label: null, text: null, shown: true };
      this.people.set(track, person);
      this.scene.add(group);
    }
    if (text !== person.text) {
      if (person.label) dispose(person.label);
      person.label = textSprite(text, colour);
      person.text = text;
      person.group.add(person.label);
    }
    return person;
  }

  // three lines: where the face points (from the head) and each hand (from its wrist)
  endLines() {
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(new Float32Array(6 * 3), 3));
    const colours = [FACE_COLOUR, FACE_COLOUR, ...HAND_COLOURS.flatMap((c) => [c, c])]
      .flatMap((c) => new THREE.Color(c).toArray());
    geometry.setAttribute('color', new THREE.BufferAttribute(new Float32Array(colours), 3));
    return new THREE.LineSegments(geometry, new THREE.LineBasicMaterial({ vertexColors: true }));
  }

  // the face's and hands' directions ({face, hands}: unit, scene frame) from the joints; none: not drawn
  placeEnds(person, p, joints) {
    const at = person.ends.geometry.attributes.position;
    const rays = [[p.face, FACE_M], [p.hands?.[0], HAND_M], [p.hands?.[1], HAND_M]];
    rays.forEach(([direction, length], i) => {
      const from = joints[this.endJoints[i]];
      const known = direction && direction[0] !== null && from.every(Number.isFinite);
      const to = known ? from.map((v, k) => v + length * direction[k]) : [NaN, NaN, NaN];
      at.setXYZ(2 * i, ...(known ? from : to));
      at.setXYZ(2 * i + 1, ...to);
    });
    at.needsUpdate = true;
  }

  // one frame's people: [{track, joints, face, hands}], the others hidden
  pose(people, info) {
    const seen = new Set();
    for (const p of people) {
      const { colour, label } = info(p);
      const person = this.person(p.track, colour, label);
      const joints = p.joints.map((j) => j.map((v) => (v === null ? NaN : v)));
      const at = person.points.geometry.attributes.position;
      joints.forEach((j, i) => at.setXYZ(i, ...j));
      at.needsUpdate = true;
      const lines = person.lines.geometry.attributes.position;
      this.skeleton.lines.forEach(([a, b], i) => { lines.setXYZ(2 * i, ...joints[a]); lines.setXYZ(2 * i + 1, ...joints[b]); });
      lines.needsUpdate = true;
      this.placeEnds(person, p, joints);
      const head = joints[0].every(Number.isFinite) ? joints[0] : joints[1];
      person.label.position.set(head[0], head[1] + 0.2, head[2]);
      person.group.visible = person.shown;
      seen.add(p.track);
    }
    for (const [track, person] of this.people) if (!seen.has(track)) person.group.visible = false;
    this.render();
  }

  drawnJoints(track) {
    const person = this.people.get(track);
    if (!person || !person.group.visible) return null;
    const at = person.points.geometry.attributes.position;
    return Array.from({ length: at.count }, (_, i) => [at.getX(i), at.getY(i), at.getZ(i)]);
  }

  // the face's and hands' lines drawn: [[from, to] × 3] (NaN: not drawn), null when the person is not shown
  drawnEnds(track) {
    const person = this.people.get(track);
    if (!person || !person.group.visible) return null;
    const at = person.ends.geometry.attributes.position;
    return [0, 1, 2].map((i) => [2 * i, 2 * i + 1].map((k) => [at.getX(k), at.getY(k), at.getZ(k)]));
  }

  // look at ``points`` (the people) and the filming camera from its side, 30° above the floor
  frame(points, cameraPosition) {
    const from = new THREE.Vector3(...(cameraPosition || [0, 1.5, 4]));
    const box = new THREE.Box3().setFromPoints([...points.map((p) => new THREE.Vector3(...p)), from]);
    const target = box.getCenter(new THREE.Vector3());
    const radius = Math.max(1.5, box.getSize(new THREE.Vector3()).length() / 2);
    const away = from.clone().sub(target).setY(0);
    if (away.lengthSq() < 1e-6) away.set(0, 0, 1);
    away.normalize().applyAxisAngle(new THREE.Vector3(0, 1, 0), 0.7);
    const distance = 1.3 * radius / Math.sin(THREE.MathUtils.degToRad(this.camera.fov / 2));
    const direction = away.multiplyScalar(Math.cos(Math.PI / 6)).setY(Math.sin(Math.PI / 6));
    this.camera.position.copy(target).addScaledVector(direction, distance);
    this.controls.target.copy(target);
    this.controls.update();
    this.render();
  }
}

// ---------------------------------------------------------------- the image panel

class ImagePanel {
  constructor(canvas, skeleton) {
    this.canvas = canvas;
    this.ctx = canvas.getContext('2d');
    this.skeleton = skeleton;
  }

  setImage(image) {
    if (!image) return;
    this.image = image;
    this.canvas.width = image.width;
    this.canvas.height = image.height;
    this.width = Math.max(2, image.width / 300);
  }

  // points ([x, y], null or [null, null]: unknown) and the ``lines`` between them; returns the lines drawn
  bones(points, colour, width, lines = this.skeleton.lines) {
    const ctx = this.ctx;
    const known = (p) => p && p[0] !== null;
    ctx.strokeStyle = ctx.fillStyle = colour;
    ctx.lineWidth = width;
    let drawn = 0;
    for (const [a, b] of lines) {
      if (known(points[a]) && known(points[b])) {
        ctx.beginPath(); ctx.moveTo(...points[a]); ctx.lineTo(...points[b]); ctx.stroke();
        drawn += 1;
      }
    }
    for (const p of points) {
      if (known(p)) { ctx.beginPath(); ctx.arc(p[0], p[1], width * 1.2, 0, 2 * Math.PI); ctx.fill(); }
    }
    return drawn;
  }

  // the input people's hands ([right, left] or null per person; a hand null when absent): the finger lines
  hands(people) {
    this.handSegments = 0;
    for (const person of people) {
      (person || []).forEach((hand, side) => {
        if (hand) this.handSegments += this.bones(hand, HAND_COLOURS[side], this.width * 0.6, this.skeleton.hand_lines);
      });
    }
  }

  // the video frame (or a dark background), the input keypoints (grey) and hands, each person re-projected
  draw(background, keypoints, hands, people, info) {
    if (!this.image) return;
    const ctx = this.ctx;
    if (background) ctx.drawImage(background, 0, 0, this.canvas.width, this.canvas.height);
    else { ctx.fillStyle = '#201e1c'; ctx.fillRect(0, 0, this.canvas.width, this.canvas.height); }
    for (const k of keypoints) this.bones(k, INPUT_COLOUR, this.width * 0.5);
    this.hands(hands);
    for (const p of people) {
      if (!p.px) continue;
      const { colour, label } = info(p);
      this.bones(p.px, colour, this.width);
      const head = p.px[0][0] !== null ? p.px[0] : p.px[1];
      if (head[0] === null) continue;
      ctx.font = `600 ${Math.round(this.width * 6)}px system-ui, sans-serif`;
      const x = Math.max(0, Math.min(head[0] - 20, this.canvas.width - ctx.measureText(label).width));
      const y = Math.max(this.width * 6, head[1] - 24);
      ctx.lineWidth = this.width * 1.5;
      ctx.strokeStyle = 'black';
      ctx.strokeText(label, x, y);
      ctx.fillStyle = colour;
      ctx.fillText(label, x, y);
    }
  }
}

// ---------------------------------------------------------------- the page

function trackList(tracks, onToggle) {
  $('tracks').replaceChildren(...tracks.map((t) => {
    const item = document.createElement('li');
    const box = Object.assign(document.createElement('input'), { type: 'checkbox', checked: true });
    box.dataset.track = t.track;
    box.addEventListener('change', () => onToggle(t.track, box.checked));
    const swatch = Object.assign(document.createElement('span'), { className: 'swatch' });
    swatch.style.background = t.colour;
    const legend = Object.assign(document.createElement('div'), { className: 'legend', textContent: t.legend });
    item.append(box, swatch, t.label, legend);
    return item;
  }));
}

class Viewer {
  constructor(meta) {
    this.meta = meta;
    this.tracks = new Map(meta.tracks.map((t) => [t.track, t]));
    this.hidden = new Set();
    this.image = new ImagePanel($('image'), meta.skeleton);
    this.image.setImage(meta.image);
    this.scene = new Scene3D($('scene'), meta.skeleton);
    this.chunks = new Map();
    this.images = new Map();  // timeline position → Promise of its video frame
    this.pos = -1;          // the timeline position drawn
    this.wanted = 0;        // the position asked for
    this.playing = false;
    this.stats = { drawn: 0, loadMs: null, playFrames: 0, playSeconds: 0, received: 0, fps: 0, latencyMs: null, dropped: 0 };
    $('title').textContent = `mocapdb · ${meta.title}`;
    $('files').replaceChildren(...meta.files.map((name) => {
      const item = document.createElement('li');
      item.append(Object.assign(document.createElement('a'),
        { href: `/files/${encodeURIComponent(name)}`, textContent: name, target: '_blank' }));
      return item;
    }));
    $('files-title').hidden = !meta.files.length;
    $('summary').replaceChildren(...[...meta.summary, meta.note].filter(Boolean).map((line) =>
      Object.assign(document.createElement('li'), { textContent: line })));
    trackList(meta.tracks, (track, shown) => this.toggle(track, shown));
    this.scene.setGrid(this.gridSize(), meta.floor_y);
    this.scene.setCameras(meta.cameras, meta.floor_y);
  }

  info = (p) => {
    const t = this.tracks.get(p.track);
    return { colour: p.colour || (t && t.colour) || '#ffffff', label: p.label || (t && t.label) || `#${p.track}` };
  };

  gridSize() {
    const xs = this.meta.cameras.flatMap((c) => [Math.abs(c.position[0]), Math.abs(c.position[2])]);
    return 2 * Math.ceil(Math.max(5, ...xs) + 2);
  }

  toggle(track, shown) {
    if (shown) this.hidden.delete(track); else this.hidden.add(track);
    const person = this.scene.people.get(track);
    if (person) person.shown = shown;
    this.redraw();
  }

  visible(people) { return people.filter((p) => !this.hidden.has(p.track)); }

  // ------------------------------------------------------------ a recorded take

  chunk(c) {
    if (!this.chunks.has(c)) {
      this.chunks.set(c, fetch(`/api/frames?from=${c * CHUNK}&count=${CHUNK}`).then((r) => r.json())
        .catch((error) => { this.chunks.delete(c); throw error; }));
    }
    return this.chunks.get(c);
  }

  async frameAt(pos) {
    const c = Math.floor(pos / CHUNK);
    if (this.playing && pos % CHUNK > CHUNK / 2 && (c + 1) * CHUNK < this.meta.frames.length) this.chunk(c + 1);
    return (await this.chunk(c))[pos - c * CHUNK];
  }

  // the video frame at timeline position ``pos``; while playing the next ones are fetched ahead
  videoFrame(pos) {
    if (!this.meta.video) return Promise.resolve(null);
    const ahead = this.playing ? VIDEO_AHEAD : 0;
    for (const key of this.images.keys()) if (key < pos || key > pos + ahead) this.images.delete(key);
    for (let p = pos; p <= Math.min(pos + ahead, this.meta.frames.length - 1); p += 1) {
      if (this.images.has(p)) continue;
      const img = new Image();
      img.src = `/video/${this.meta.frames[p]}.jpg`;
      this.images.set(p, img.decode().then(() => img, () => null));
    }
    return this.images.get(pos);
  }

  // draw timeline position ``pos`` (the newest request wins; older ones are dropped)
  async show(pos) {
    this.wanted = pos;
    if (this.busy) return this.busy;
    this.busy = (async () => {
      try {
        while (this.pos !== this.wanted) {
          const target = this.wanted;
          const frame = await this.frameAt(target);
          const background = await this.videoFrame(target);
          this.current = frame;
          this.redraw(background);
          this.pos = target;
          this.stats.drawn += 1;
          if (this.playing) this.stats.playFrames += 1;
          $('scrub').value = target;
          $('frame-label').textContent = `frame ${frame.frame} · ${frame.time.toFixed(2)} s`;
        }
      } finally {
        this.busy = null;
      }
    })();
    return this.busy;
  }

  redraw(background) {
    const frame = this.current;
    if (!frame) return;
    if (background !== undefined) this.background = background;
    const people = this.visible(frame.people);
    this.image.draw(this.background, frame.keypoints || [], frame.hands || [], people, this.info);
    this.scene.pose(people, this.info);
  }

  play() {
    if (this.playing) return;
    const from = this.pos >= this.meta.frames.length - 1 ? 0 : Math.max(0, this.pos);
    this.playing = true;
    Object.assign(this.stats, { playFrames: 0, playSeconds: 0 });
    $('play').textContent = '❚❚';
    const start = performance.now();
    const tick = (now) => {
      if (!this.playing) return;
      const pos = from + Math.floor((now - start) / 1000 * this.meta.fps);
      this.stats.playSeconds = (now - start) / 1000;
      if (pos >= this.meta.frames.length) { this.pause(); this.show(this.meta.frames.length - 1); return; }
      if (pos !== this.wanted) this.show(pos);
      requestAnimationFrame(tick);
    };
    requestAnimationFrame(tick);
  }

  pause() {
    this.playing = false;
    $('play').textContent = '▶';
  }

  step(by) {
    this.pause();
    return this.show(Math.min(this.meta.frames.length - 1, Math.max(0, this.pos + by)));
  }

  async startTake() {
    const scrub = $('scrub');
    scrub.max = this.meta.frames.length - 1;
    scrub.addEventListener('input', () => { this.pause(); this.show(Number(scrub.value)); });
    $('play').addEventListener('click', () => (this.playing ? this.pause() : this.play()));
    $('prev').addEventListener('click', () => this.step(-1));
    $('next').addEventListener('click', () => this.step(1));
    document.addEventListener('keydown', (e) => {
      if (e.target.tagName === 'INPUT' && e.target.type !== 'range') return;
      if (e.key === ' ') { e.preventDefault(); this.playing ? this.pause() : this.play(); }
      if (e.key === 'ArrowLeft') { e.preventDefault(); this.step(-1); }
      if (e.key === 'ArrowRight') { e.preventDefault(); this.step(1); }
    });
    await this.show(0);
    this.lookAtPeople((await this.chunk(0)).flatMap((f) => f.people), this.meta.cameras);
    $('status').textContent = `${this.meta.frames.length} frames · ${this.meta.fps} fps`;
  }

  lookAtPeople(people, cameras) {
    const pelvis = people.map((p) => p.joints[p.joints.length - 1]).filter((j) => j[0] !== null);
    if (!pelvis.length) return false;
    this.scene.frame(pelvis, cameras[0]?.position);
    return true;
  }

  // ------------------------------------------------------------ a live stream

  startLive() {
    document.body.classList.add('live');
    const arrivals = [];
    let framed = false;
    const source = new EventSource('/api/live');
    source.onmessage = (message) => {
      const event = JSON.parse(message.data);
      if (event.type === 'header') {
        this.image.setImage(event.image);
        if (event.fps) this.meta.fps = event.fps;
        return;
      }
      const now = performance.now();
      arrivals.push(now);
      while (arrivals.length > 1 && now - arrivals[0] > 2000) arrivals.shift();
      Object.assign(this.stats, {
        received: this.stats.received + 1, dropped: event.dropped, latencyMs: Date.now() - event.sent_ms,
        fps: arrivals.length > 1 ? (arrivals.length - 1) / ((now - arrivals[0]) / 1000) : 0,
      });
      this.current = { frame: event.frame, time: event.time, people: event.people,
        keypoints: event.people.filter((p) => p.keypoints && !this.hidden.has(p.track)).map((p) => p.keypoints) };
      this.scene.setGrid(10, event.floor_y);
      this.scene.setCameras([event.camera], event.floor_y);
      for (const p of event.people) {
        if (!this.tracks.has(p.track)) {
          this.tracks.set(p.track, { track: p.track, label: `#${p.track}`, legend: '', colour: p.colour });
          trackList([...this.tracks.values()], (track, shown) => this.toggle(track, shown));
        }
      }
      this.redraw(null);
      if (!framed) framed = this.lookAtPeople(event.people, [event.camera]);
      this.stats.drawn += 1;
      $('status').textContent = `live · frame ${event.frame} · ${this.stats.fps.toFixed(1)} frames/s · latency `
        + `${this.stats.latencyMs.toFixed(0)} ms · dropped ${event.dropped}`;
    };
    source.addEventListener('end', () => { source.close(); $('status').textContent += ' · the stream ended'; });
    source.onerror = () => { source.close(); $('status').textContent += ' · disconnected'; };
    $('status').textContent = 'live · waiting for the stream';
  }
}

async function main() {
  const meta = await (await fetch('/api/take')).json();
  const viewer = new Viewer(meta);
  window.mocapdbViewer = {
    viewer,
    frame: () => viewer.current?.frame,
    seek: (frame) => viewer.show(meta.frames.indexOf(frame)),
    pose: async (track, frame) => {
      if (frame !== undefined && frame !== viewer.current?.frame) { viewer.pause(); await viewer.show(meta.frames.indexOf(frame)); }
      return viewer.scene.drawnJoints(track);
    },
    ends: (track) => viewer.scene.drawnEnds(track),
    handSegments: () => viewer.image.handSegments,
    play: () => viewer.play(),
    pause: () => viewer.pause(),
    stats: () => ({ ...viewer.stats, playing: viewer.playing,
      playFps: viewer.stats.playSeconds ? viewer.stats.playFrames / viewer.stats.playSeconds : null }),
  };
  if (meta.kind === 'live') viewer.startLive();
  else await viewer.startTake();
  viewer.stats.loadMs = performance.now();   // since the navigation started
  window.mocapdbViewer.ready = true;
}

main();
