//! Scene families: seeded generators of scene permutations, like the KPCN training set
//! (environment rotation and sun position, roughness, textures within a class, light
//! intensity, camera position and field of view, pinhole or thin lens).

use super::rng::Rng;
use super::scene::{
    CameraDesc, Effect, EnvDesc, EnvType, LightDesc, LightType, MaterialDesc, MaterialType, ObjectDesc, SceneDesc,
    ShapeKind, SunDesc, TextureDesc,
};
use super::texture::{Pattern, Texture};

/// (name, description) of every family.
pub const FAMILIES: [(&str, &str); 9] = [
    ("cornell", "Cornell-style box: coloured walls, ceiling light, blocks and a sphere"),
    ("interior", "room lit by sky and sun through a window, textured floor, table"),
    ("courtyard", "outdoor courtyard under a sky with a sun, textured ground, buildings"),
    ("product", "product shot: glossy metal and plastic objects, area light, studio environment"),
    ("glass", "glass objects on a table under an area light and a sky"),
    ("dof", "still life at several depths through a thin lens"),
    ("firefly", "dark room lit by a small bright light and a spot: caustics and fireflies"),
    ("corridor", "long corridor with striped, wood and marble walls lit by spots"),
    ("slit", "closed room lit only by sky and sun through a narrow slit: sparse indirect light"),
];

/// Generates permutation `seed` of family `name`; `None` for an unknown family.
pub fn generate(name: &str, seed: u64) -> Option<SceneDesc> {
    let index = FAMILIES.iter().position(|(n, _)| *n == name)?;
    let mut b = Builder::new(&format!("{name}-{seed:04}"), Rng::for_sample(seed, index as u64, 0xFA41));
    match name {
        "cornell" => cornell(&mut b),
        "interior" => interior(&mut b),
        "courtyard" => courtyard(&mut b),
        "product" => product(&mut b),
        "glass" => glass(&mut b),
        "dof" => dof(&mut b),
        "firefly" => firefly(&mut b),
        "slit" => slit(&mut b),
        _ => corridor(&mut b),
    }
    Some(b.d)
}

struct Builder {
    d: SceneDesc,
    // Interior mutability lets `b.u(..)` appear inside the arguments of `b.object(..)`.
    rng: std::cell::RefCell<Rng>,
}

fn tex(pattern: Pattern, color: [f32; 3], color2: [f32; 3], scale: f32) -> TextureDesc {
    TextureDesc::Texture(Texture { pattern, color, color2, scale })
}

impl Builder {
    fn new(name: &str, rng: Rng) -> Self {
        let camera = CameraDesc {
            position: [0.0, 1.0, 4.0],
            look_at: [0.0, 1.0, 0.0],
            up: [0.0, 1.0, 0.0],
            fov: 40.0,
            aperture: 0.0,
            focus_distance: None,
        };
        let d = SceneDesc {
            name: name.into(),
            effects: vec![Effect::Indirect],
            max_depth: 8,
            camera,
            materials: vec![],
            objects: vec![],
            lights: vec![],
            environment: None,
        };
        Builder { d, rng: std::cell::RefCell::new(rng) }
    }

    fn r(&self) -> f32 {
        self.rng.borrow_mut().uniform()
    }

    fn u(&self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.r()
    }

    fn pick<T: Copy>(&self, xs: &[T]) -> T {
        xs[((self.r() * xs.len() as f32) as usize).min(xs.len() - 1)]
    }

    fn effect(&mut self, e: Effect) {
        if !self.d.effects.contains(&e) {
            self.d.effects.push(e);
        }
    }

    fn material(&mut self, name: &str, kind: MaterialType) -> &mut MaterialDesc {
        self.d.materials.push(MaterialDesc {
            name: name.into(),
            kind,
            albedo: None,
            color: None,
            roughness: 0.0,
            ior: None,
            radiance: None,
        });
        self.d.materials.last_mut().expect("just pushed")
    }

    fn diffuse(&mut self, name: &str, albedo: TextureDesc) {
        if matches!(albedo, TextureDesc::Texture(_)) {
            self.effect(Effect::Textures);
        }
        self.material(name, MaterialType::Diffuse).albedo = Some(albedo);
    }

    fn conductor(&mut self, name: &str, color: [f32; 3], roughness: f32) {
        self.effect(Effect::Glossy);
        let m = self.material(name, MaterialType::Conductor);
        m.color = Some(color);
        m.roughness = roughness;
    }

    fn plastic(&mut self, name: &str, albedo: [f32; 3], roughness: f32) {
        self.effect(Effect::Glossy);
        let m = self.material(name, MaterialType::Plastic);
        m.albedo = Some(TextureDesc::Color(albedo));
        m.roughness = roughness;
    }

    fn glass(&mut self, name: &str, roughness: f32) {
        self.effect(Effect::Transmission);
        if roughness > 0.0 {
            self.effect(Effect::Glossy);
        }
        let m = self.material(name, MaterialType::Dielectric);
        m.ior = Some(1.5);
        m.roughness = roughness;
    }

    fn emitter(&mut self, name: &str, radiance: [f32; 3]) {
        self.effect(Effect::AreaLights);
        self.material(name, MaterialType::Emissive).radiance = Some(radiance);
    }

    fn object(&mut self, shape: ShapeKind, material: &str, translate: [f32; 3], rotate: [f32; 3], scale: [f32; 3]) {
        self.d.objects.push(ObjectDesc { shape, material: material.into(), translate, rotate, scale });
    }

    fn spot(&mut self, position: [f32; 3], direction: [f32; 3], intensity: [f32; 3], cone: f32) {
        self.effect(Effect::PointLights);
        self.d.lights.push(LightDesc {
            kind: LightType::Spot,
            position,
            intensity,
            direction: Some(direction),
            cone_angle: Some(cone),
        });
    }

    fn sky(&mut self, strength: f32, sun: Option<(f32, f32, f32)>) {
        self.effect(Effect::Environment);
        let rotation = self.u(0.0, 360.0);
        let sun = sun.map(|(elevation, azimuth, e)| {
            self.effect(Effect::Sun);
            SunDesc { elevation, azimuth, irradiance: [e, e * 0.92, e * 0.8], angular_diameter: 2.0 }
        });
        self.d.environment = Some(EnvDesc { kind: EnvType::Sky, color: [strength; 3], rotation, sun });
    }

    /// A `w` × `h` × `d` room centred on the origin, floor at 0, without its far wall
    /// (z = −d/2), which [`Builder::wall_with_opening`] builds.
    fn room_without_far_wall(&mut self, floor: &str, wall: &str, (w, h, d): (f32, f32, f32)) {
        self.object(ShapeKind::Quad, floor, [0.0, 0.0, 0.0], [0.0; 3], [w, 1.0, d]);
        self.object(ShapeKind::Quad, wall, [0.0, h, 0.0], [180.0, 0.0, 0.0], [w, 1.0, d]);
        self.object(ShapeKind::Quad, wall, [-w / 2.0, h / 2.0, 0.0], [0.0, 0.0, -90.0], [h, 1.0, d]);
        self.object(ShapeKind::Quad, wall, [w / 2.0, h / 2.0, 0.0], [0.0, 0.0, 90.0], [h, 1.0, d]);
        self.object(ShapeKind::Quad, wall, [0.0, h / 2.0, d / 2.0], [-90.0, 0.0, 0.0], [w, 1.0, h]);
    }

    /// The wall at depth `z` of a `w` × `h` room, built around a centred opening
    /// `open_w` wide from height `y0` to `y1`.
    fn wall_with_opening(&mut self, material: &str, z: f32, (w, h): (f32, f32), (open_w, y0, y1): (f32, f32, f32)) {
        self.object(ShapeKind::Quad, material, [0.0, y0 / 2.0, z], [90.0, 0.0, 0.0], [w, 1.0, y0]);
        self.object(ShapeKind::Quad, material, [0.0, (y1 + h) / 2.0, z], [90.0, 0.0, 0.0], [w, 1.0, h - y1]);
        let side = (w - open_w) / 2.0;
        for sx in [-1.0, 1.0] {
            self.object(
                ShapeKind::Quad,
                material,
                [sx * (open_w + side) / 2.0, (y0 + y1) / 2.0, z],
                [90.0, 0.0, 0.0],
                [side, 1.0, y1 - y0],
            );
        }
    }

    fn constant_env(&mut self, c: f32) {
        self.effect(Effect::Environment);
        self.d.environment = Some(EnvDesc { kind: EnvType::Constant, color: [c; 3], rotation: 0.0, sun: None });
    }

    /// Jittered camera around a base pose; sometimes a thin lens focused on `look_at`.
    fn camera(&mut self, position: [f32; 3], look_at: [f32; 3], fov: f32, jitter: f32) {
        let p = position.map(|v| v + jitter * (self.r() - 0.5));
        let fov = fov * self.u(0.85, 1.15);
        let lens = self.r() < 0.3;
        let aperture = if lens { self.u(0.01, 0.05) } else { 0.0 };
        if lens {
            self.effect(Effect::DepthOfField);
        }
        self.d.camera = CameraDesc { position: p, look_at, up: [0.0, 1.0, 0.0], fov, aperture, focus_distance: None };
    }

    fn color(&self, base: [f32; 3], spread: f32) -> [f32; 3] {
        base.map(|c| (c + spread * (self.r() - 0.5)).clamp(0.02, 0.95))
    }

    /// A random texture of the given classes.
    fn texture(&self, classes: &[Pattern], a: [f32; 3], b: [f32; 3]) -> TextureDesc {
        let p = self.pick(classes);
        let scale = self.u(1.5, 5.0);
        let (a, b) = (self.color(a, 0.15), self.color(b, 0.15));
        tex(p, a, b, scale)
    }

    /// Floor, ceiling and walls of a box room `w`×`h`×`d` (floor at y = 0, open towards +z
    /// when `open_front`).
    fn room(&mut self, w: f32, h: f32, d: f32, floor: &str, walls: [&str; 3], ceiling: &str) {
        self.object(ShapeKind::Quad, floor, [0.0, 0.0, 0.0], [0.0; 3], [w, 1.0, d]);
        self.object(ShapeKind::Quad, ceiling, [0.0, h, 0.0], [180.0, 0.0, 0.0], [w, 1.0, d]);
        self.object(ShapeKind::Quad, walls[0], [-w / 2.0, h / 2.0, 0.0], [0.0, 0.0, -90.0], [h, 1.0, d]);
        self.object(ShapeKind::Quad, walls[1], [w / 2.0, h / 2.0, 0.0], [0.0, 0.0, 90.0], [h, 1.0, d]);
        self.object(ShapeKind::Quad, walls[2], [0.0, h / 2.0, -d / 2.0], [90.0, 0.0, 0.0], [w, 1.0, h]);
    }
}

fn cornell(b: &mut Builder) {
    let (red, green) = (b.color([0.63, 0.065, 0.05], 0.2), b.color([0.14, 0.45, 0.09], 0.2));
    b.diffuse("white", TextureDesc::Color([0.73, 0.71, 0.68]));
    b.diffuse("red", TextureDesc::Color(red));
    b.diffuse("green", TextureDesc::Color(green));
    let power = b.u(8.0, 25.0);
    b.emitter("light", [power, power * 0.85, power * 0.6]);
    b.room(2.0, 2.0, 2.0, "white", ["red", "green", "white"], "white");
    b.object(ShapeKind::Quad, "light", [0.0, 1.99, 0.0], [180.0, 0.0, 0.0], [0.5, 1.0, 0.4]);
    let (r1, r2) = (b.u(-30.0, 30.0), b.u(-30.0, 30.0));
    b.object(ShapeKind::Box, "white", [-0.35, 0.6, -0.3], [0.0, r1, 0.0], [0.55, 1.2, 0.55]);
    if b.r() < 0.5 {
        let rough = b.u(0.05, 0.4);
        b.conductor("metal", [0.95, 0.93, 0.88], rough);
        b.object(ShapeKind::Sphere, "metal", [0.4, 0.3, 0.3], [0.0; 3], [0.3; 3]);
    } else {
        b.object(ShapeKind::Box, "white", [0.4, 0.3, 0.3], [0.0, r2, 0.0], [0.55, 0.6, 0.55]);
    }
    b.camera([0.0, 1.0, 3.9], [0.0, 1.0, 0.0], 38.0, 0.3);
}

fn interior(b: &mut Builder) {
    let floor = b.texture(&[Pattern::Checker, Pattern::Wood], [0.7, 0.65, 0.6], [0.25, 0.2, 0.15]);
    b.diffuse("floor", floor);
    let wall = b.color([0.75, 0.72, 0.68], 0.2);
    b.diffuse("wall", TextureDesc::Color(wall));
    let wood = b.texture(&[Pattern::Wood, Pattern::Noise], [0.55, 0.35, 0.2], [0.3, 0.18, 0.1]);
    b.diffuse("wood", wood);
    b.diffuse("cloth", TextureDesc::Color([0.2, 0.3, 0.6]));
    let (w, h, d) = (6.0, 2.8, 6.0);
    // The back wall is built around a window.
    b.room_without_far_wall("floor", "wall", (w, h, d));
    b.wall_with_opening("wall", -d / 2.0, (w, h), (3.0, 0.9, 2.3));
    b.object(ShapeKind::Box, "wood", [0.3, 0.4, -1.0], [0.0, b.u(-20.0, 20.0), 0.0], [1.4, 0.8, 0.9]);
    b.object(ShapeKind::Sphere, "cloth", [0.3, 1.05, -1.0], [0.0; 3], [0.25; 3]);
    b.object(ShapeKind::Cylinder, "wood", [-1.5, 0.5, -0.5], [0.0; 3], [0.5, 1.0, 0.5]);
    let (el, az) = (b.u(20.0, 45.0), b.u(240.0, 300.0));
    let e = b.u(600.0, 1200.0) / std::f32::consts::PI;
    b.sky(b.u(0.7, 1.3), Some((el, az, e * 0.01)));
    // The sky's rotation must not turn the sun away from the window: keep it fixed here.
    if let Some(env) = b.d.environment.as_mut() {
        env.rotation = 0.0;
    }
    b.camera([0.0, 1.5, 2.6], [0.0, 1.0, -3.0], 60.0, 0.6);
}

fn slit(b: &mut Builder) {
    let wall = b.color([0.75, 0.72, 0.68], 0.2);
    b.diffuse("wall", TextureDesc::Color(wall));
    let floor = b.texture(&[Pattern::Wood, Pattern::Checker, Pattern::Noise], [0.6, 0.5, 0.4], [0.3, 0.25, 0.2]);
    b.diffuse("floor", floor);
    let pc = b.color([0.6, 0.25, 0.2], 0.5);
    let pr = b.u(0.1, 0.4);
    b.plastic("plastic", pc, pr);
    let (w, h, d) = (5.0, 2.8, 5.0);
    // A closed room but for a narrow slit, vertical or horizontal, in the far wall: all
    // light comes through it, most of it after bounces (failure mode: sparse indirect light).
    b.room_without_far_wall("floor", "wall", (w, h, d));
    let gap = b.u(0.08, 0.25);
    let opening = if b.r() < 0.5 { (gap, 0.4, 2.4) } else { (b.u(1.5, 3.5), h - 0.4 - gap, h - 0.4) };
    b.wall_with_opening("wall", -d / 2.0, (w, h), opening);
    b.object(ShapeKind::Box, "wall", [b.u(-1.5, 1.5), 0.45, b.u(-1.5, 0.5)], [0.0, b.u(0.0, 90.0), 0.0], [0.9; 3]);
    b.object(ShapeKind::Sphere, "plastic", [b.u(-1.5, 1.5), 0.4, b.u(-1.0, 1.0)], [0.0; 3], [0.4; 3]);
    b.object(ShapeKind::Cylinder, "floor", [b.u(-2.0, 2.0), 0.6, b.u(-2.0, 0.0)], [0.0; 3], [0.3, 1.2, 0.3]);
    // A strong sun: the patch it throws through the slit is the room's only bright light.
    let (el, az) = (b.u(15.0, 40.0), b.u(250.0, 290.0));
    let e = b.u(200.0, 600.0);
    b.sky(b.u(0.5, 1.0), Some((el, az, e)));
    // Keep the sun facing the slit (see `interior`).
    if let Some(env) = b.d.environment.as_mut() {
        env.rotation = 0.0;
    }
    let x = b.u(-1.0, 1.0);
    b.camera([x, 1.5, 2.2], [-x, b.u(0.6, 1.2), -2.5], 65.0, 0.6);
}

fn courtyard(b: &mut Builder) {
    let ground = b.texture(&[Pattern::Checker, Pattern::Noise, Pattern::Stripes], [0.55, 0.5, 0.45], [0.3, 0.28, 0.25]);
    b.diffuse("ground", ground);
    let c1 = b.color([0.7, 0.55, 0.4], 0.3);
    let c2 = b.color([0.6, 0.6, 0.65], 0.3);
    b.diffuse("building", TextureDesc::Color(c1));
    b.diffuse("stone", TextureDesc::Color(c2));
    b.object(ShapeKind::Quad, "ground", [0.0; 3], [0.0; 3], [40.0, 1.0, 40.0]);
    for i in 0..5 {
        let (x, z) = (b.u(-6.0, 6.0), b.u(-8.0, -2.0));
        let hgt = b.u(1.0, 4.0);
        let m = if i % 2 == 0 { "building" } else { "stone" };
        b.object(ShapeKind::Box, m, [x, hgt / 2.0, z], [0.0, b.u(0.0, 90.0), 0.0], [b.u(1.0, 2.5), hgt, b.u(1.0, 2.5)]);
    }
    b.object(ShapeKind::Sphere, "stone", [0.5, 0.5, 0.0], [0.0; 3], [0.5; 3]);
    let (el, az) = (b.u(10.0, 70.0), b.u(0.0, 360.0));
    let e = b.u(2.0, 5.0);
    b.sky(1.0, Some((el, az, e)));
    b.camera([0.0, 1.6, 6.0], [0.0, 1.0, -2.0], 55.0, 1.0);
}

fn product(b: &mut Builder) {
    let base = b.color([0.5, 0.5, 0.52], 0.3);
    b.diffuse("backdrop", TextureDesc::Color(base));
    let metal = b.pick(&[[0.95, 0.64, 0.54], [0.91, 0.92, 0.92], [1.0, 0.78, 0.34]]);
    let r = b.u(0.05, 0.5);
    b.conductor("metal", metal, r);
    let pc = b.color([0.2, 0.5, 0.3], 0.6);
    let pr = b.u(0.05, 0.5);
    b.plastic("plastic", pc, pr);
    let power = b.u(4.0, 12.0);
    b.emitter("softbox", [power; 3]);
    b.object(ShapeKind::Quad, "backdrop", [0.0; 3], [0.0; 3], [10.0, 1.0, 10.0]);
    b.object(ShapeKind::Sphere, "metal", [-0.6, 0.5, 0.0], [0.0; 3], [0.5; 3]);
    b.object(ShapeKind::Torus, "plastic", [0.7, 0.35, 0.2], [b.u(0.0, 90.0), 0.0, 0.0], [0.5; 3]);
    b.object(ShapeKind::Quad, "softbox", [0.0, 3.0, 1.0], [150.0, 0.0, 0.0], [2.0, 1.0, 1.5]);
    b.constant_env(b.u(0.05, 0.3));
    b.camera([0.0, 1.2, 3.5], [0.0, 0.4, 0.0], 35.0, 0.6);
}

fn glass(b: &mut Builder) {
    let table = b.texture(&[Pattern::Wood, Pattern::Marble], [0.6, 0.4, 0.25], [0.35, 0.2, 0.1]);
    b.diffuse("table", table);
    let rough = if b.r() < 0.5 { 0.0 } else { b.u(0.05, 0.3) };
    b.glass("glass", rough);
    b.glass("clear", 0.0);
    b.diffuse("fruit", TextureDesc::Color([0.7, 0.2, 0.1]));
    let power = b.u(5.0, 15.0);
    b.emitter("lamp", [power, power * 0.9, power * 0.8]);
    b.object(ShapeKind::Quad, "table", [0.0; 3], [0.0; 3], [8.0, 1.0, 8.0]);
    b.object(ShapeKind::Sphere, "clear", [-0.5, 0.4, 0.0], [0.0; 3], [0.4; 3]);
    b.object(ShapeKind::Cylinder, "glass", [0.5, 0.45, -0.3], [0.0; 3], [0.5, 0.9, 0.5]);
    b.object(ShapeKind::Sphere, "fruit", [0.1, 0.2, 0.6], [0.0; 3], [0.2; 3]);
    b.object(ShapeKind::Quad, "lamp", [1.5, 3.0, 1.0], [160.0, 0.0, 20.0], [1.0, 1.0, 1.0]);
    b.sky(b.u(0.3, 0.8), None);
    b.camera([0.0, 1.3, 3.2], [0.0, 0.4, 0.0], 40.0, 0.5);
}

fn dof(b: &mut Builder) {
    let ground = b.texture(&[Pattern::Checker, Pattern::Stripes], [0.8, 0.8, 0.8], [0.1, 0.1, 0.1]);
    b.diffuse("ground", ground);
    for (i, c) in [[0.8, 0.2, 0.2], [0.2, 0.7, 0.2], [0.2, 0.3, 0.8], [0.8, 0.7, 0.2]].iter().enumerate() {
        b.diffuse(&format!("ball{i}"), TextureDesc::Color(*c));
    }
    let power = b.u(3.0, 8.0);
    b.emitter("light", [power; 3]);
    b.object(ShapeKind::Quad, "ground", [0.0; 3], [0.0; 3], [20.0, 1.0, 20.0]);
    for i in 0..4 {
        let z = 1.5 - 1.6 * i as f32;
        b.object(ShapeKind::Sphere, &format!("ball{i}"), [b.u(-0.8, 0.8), 0.35, z], [0.0; 3], [0.35; 3]);
    }
    b.object(ShapeKind::Quad, "light", [0.0, 4.0, 0.0], [180.0, 0.0, 0.0], [3.0, 1.0, 3.0]);
    b.constant_env(0.1);
    b.camera([0.0, 0.8, 4.0], [0.0, 0.4, -0.1], 40.0, 0.3);
    // This family is about defocus: always a thin lens, focused on a random ball depth.
    let focus = b.u(2.5, 7.0);
    b.effect(Effect::DepthOfField);
    b.d.camera.aperture = b.u(0.05, 0.15);
    b.d.camera.focus_distance = Some(focus);
}

fn firefly(b: &mut Builder) {
    b.diffuse("wall", TextureDesc::Color([0.6, 0.6, 0.6]));
    let r = b.u(0.02, 0.2);
    b.conductor("chrome", [0.9, 0.9, 0.9], r);
    let power = b.u(300.0, 1500.0);
    b.emitter("bulb", [power, power * 0.8, power * 0.5]);
    b.room(4.0, 3.0, 4.0, "wall", ["wall", "wall", "wall"], "wall");
    b.object(ShapeKind::Sphere, "bulb", [b.u(-1.0, 1.0), 2.6, -1.0], [0.0; 3], [0.04; 3]);
    b.object(ShapeKind::Torus, "chrome", [0.0, 0.5, -0.5], [b.u(0.0, 60.0), 0.0, 0.0], [0.5; 3]);
    b.object(ShapeKind::Box, "wall", [-1.0, 0.4, -1.2], [0.0, 30.0, 0.0], [0.8; 3]);
    let e = b.u(2.0, 8.0);
    b.spot([1.5, 2.8, 1.5], [-0.5, -1.0, -0.5], [e; 3], 25.0);
    b.camera([0.0, 1.4, 1.9], [0.0, 0.8, -1.0], 55.0, 0.4);
}

fn corridor(b: &mut Builder) {
    let walls = b.texture(&[Pattern::Stripes, Pattern::Wood, Pattern::Marble], [0.7, 0.68, 0.6], [0.35, 0.3, 0.25]);
    b.diffuse("walls", walls);
    let floor = b.texture(&[Pattern::Checker, Pattern::Marble], [0.8, 0.8, 0.78], [0.2, 0.2, 0.22]);
    b.diffuse("floor", floor);
    b.diffuse("ceiling", TextureDesc::Color([0.8, 0.8, 0.8]));
    b.room(2.5, 3.0, 16.0, "floor", ["walls", "walls", "walls"], "ceiling");
    let e = b.u(3.0, 9.0);
    for i in 0..4 {
        let z = 6.0 - 4.0 * i as f32;
        b.spot([0.0, 2.9, z], [0.0, -1.0, 0.0], [e, e * 0.9, e * 0.75], b.u(30.0, 50.0));
    }
    b.camera([0.0, 1.6, 7.5], [0.0, 1.4, -6.0], 50.0, 0.5);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_family_builds_and_declares_exactly_what_it_uses() {
        for (name, _) in FAMILIES {
            for seed in 0..6 {
                let d = generate(name, seed).unwrap();
                d.build(16.0 / 9.0).unwrap_or_else(|e| panic!("{name} {seed}: {e}"));
                // Round trip through TOML.
                let again = SceneDesc::parse(&d.to_toml(), name).unwrap();
                assert_eq!(again, d);
            }
        }
    }

    #[test]
    fn seeds_permute_the_scene() {
        assert_ne!(generate("cornell", 1), generate("cornell", 2));
        assert_eq!(generate("cornell", 3), generate("cornell", 3));
        assert!(generate("nope", 1).is_none());
    }
}
