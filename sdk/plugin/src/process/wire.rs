//! The wire format: length-prefixed messages of little-endian numbers, IEEE bits and
//! length-prefixed strings, and the typed readers and writers both sides use.

use super::*;

/// A message being written (the four length bytes first, filled in by [`Enc::finish`]).
#[derive(Debug, Default)]
pub(crate) struct Enc(pub(crate) Vec<u8>);

impl Enc {
    pub(crate) fn start(&mut self, tag: u8) {
        self.0.clear();
        self.0.extend_from_slice(&[0, 0, 0, 0, tag]);
    }
    pub(crate) fn finish(&mut self) -> &[u8] {
        let n = (self.0.len() - 4) as u32;
        self.0[..4].copy_from_slice(&n.to_le_bytes());
        &self.0
    }
    pub(crate) fn u8(&mut self, v: u8) {
        self.0.push(v);
    }
    pub(crate) fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(crate) fn f64(&mut self, v: f64) {
        self.0.extend_from_slice(&v.to_bits().to_le_bytes());
    }
    pub(crate) fn f64s(&mut self, v: &[f64]) {
        self.u64(v.len() as u64);
        for &x in v {
            self.f64(x);
        }
    }
    pub(crate) fn str(&mut self, s: &str) {
        self.u64(s.len() as u64);
        self.0.extend_from_slice(s.as_bytes());
    }
    pub(crate) fn pose(&mut self, p: Pose2) {
        self.f64(p.x);
        self.f64(p.y);
        self.f64(p.theta);
    }
    pub(crate) fn twist(&mut self, t: Twist2) {
        self.f64(t.vx);
        self.f64(t.vy);
        self.f64(t.omega);
    }
    pub(crate) fn state(&mut self, s: &RobotState) {
        self.pose(s.pose);
        self.twist(s.velocity);
    }
    pub(crate) fn opt_str(&mut self, s: Option<&str>) {
        match s {
            Some(s) => {
                self.u8(1);
                self.str(s);
            }
            None => self.u8(0),
        }
    }
    pub(crate) fn limits(&mut self, l: &Limits) {
        for v in [l.v_max, l.v_reverse_max, l.a_max, l.omega_max] {
            self.f64(v);
        }
        match l.kappa_max {
            Some(k) => {
                self.u8(1);
                self.f64(k);
            }
            None => self.u8(0),
        }
        self.f64(l.lateral_speed_max);
    }
    pub(crate) fn agents(&mut self, agents: &[AgentState]) {
        self.u64(agents.len() as u64);
        for a in agents {
            self.u64(a.id);
            for v in [a.position[0], a.position[1], a.velocity[0], a.velocity[1]] {
                self.f64(v);
            }
            self.f64(a.radius);
            self.u64(a.history.len() as u64);
            for h in &a.history {
                self.f64(h[0]);
                self.f64(h[1]);
            }
        }
    }
    pub(crate) fn obstacles(&mut self, obstacles: &[Obstacle]) {
        self.u64(obstacles.len() as u64);
        for o in obstacles {
            match o {
                Obstacle::Circle { center, radius } => {
                    self.u8(0);
                    self.f64s(&[center[0], center[1], *radius]);
                }
                Obstacle::Segment { a, b } => {
                    self.u8(1);
                    self.f64s(&[a[0], a[1], b[0], b[1]]);
                }
                Obstacle::Polygon { vertices } => {
                    self.u8(2);
                    let flat: Vec<f64> = vertices.iter().flatten().copied().collect();
                    self.f64s(&flat);
                }
            }
        }
    }
    pub(crate) fn occupancy(&mut self, grid: Option<&OccupancyGrid>) {
        let Some(g) = grid else {
            self.u8(0);
            return;
        };
        self.u8(1);
        self.pose(g.origin);
        self.f64(g.resolution);
        self.u64(g.width as u64);
        self.u64(g.height as u64);
        self.u8(g.occupied_threshold.to_le_bytes()[0]);
        self.u64(g.data.len() as u64);
        self.0.extend(g.data.iter().map(|c| c.to_le_bytes()[0]));
    }
}

/// A message being read; every read checks the length (a short message is an error).
#[derive(Debug)]
pub(crate) struct Dec<'a> {
    buf: &'a [u8],
    at: usize,
}

impl<'a> Dec<'a> {
    pub(crate) fn new(buf: &'a [u8]) -> Self {
        Self { buf, at: 0 }
    }
    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.buf.len());
        let Some(end) = end else {
            return Err(format!(
                "message of {} bytes cut short at byte {}",
                self.buf.len(),
                self.at
            ));
        };
        let s = &self.buf[self.at..end];
        self.at = end;
        Ok(s)
    }
    pub(crate) fn u8(&mut self) -> Result<u8, String> {
        Ok(self.take(1)?[0])
    }
    pub(crate) fn u64(&mut self) -> Result<u64, String> {
        let mut b = [0u8; 8];
        b.copy_from_slice(self.take(8)?);
        Ok(u64::from_le_bytes(b))
    }
    /// A count of items of at least `item_bytes` each (checked against what is left).
    pub(crate) fn count(&mut self, item_bytes: usize) -> Result<usize, String> {
        let n = self.u64()?;
        let left = (self.buf.len() - self.at) as u64;
        if n.saturating_mul(item_bytes.max(1) as u64) > left {
            return Err(format!("a count of {n} exceeds the message"));
        }
        Ok(n as usize)
    }
    pub(crate) fn f64(&mut self) -> Result<f64, String> {
        Ok(f64::from_bits(self.u64()?))
    }
    pub(crate) fn f64s_into(&mut self, out: &mut Vec<f64>) -> Result<(), String> {
        let n = self.count(8)?;
        out.clear();
        out.reserve(n);
        for _ in 0..n {
            out.push(self.f64()?);
        }
        Ok(())
    }
    pub(crate) fn str(&mut self) -> Result<String, String> {
        let n = self.count(1)?;
        String::from_utf8(self.take(n)?.to_vec()).map_err(|e| format!("a string: {e}"))
    }
    pub(crate) fn pose(&mut self) -> Result<Pose2, String> {
        Ok(Pose2::new(self.f64()?, self.f64()?, self.f64()?))
    }
    pub(crate) fn twist(&mut self) -> Result<Twist2, String> {
        Ok(Twist2::new(self.f64()?, self.f64()?, self.f64()?))
    }
    pub(crate) fn state(&mut self) -> Result<RobotState, String> {
        Ok(RobotState {
            pose: self.pose()?,
            velocity: self.twist()?,
        })
    }
    pub(crate) fn opt_str(&mut self) -> Result<Option<String>, String> {
        Ok(match self.u8()? {
            0 => None,
            _ => Some(self.str()?),
        })
    }
    pub(crate) fn limits(&mut self) -> Result<Limits, String> {
        let (v_max, v_reverse_max, a_max, omega_max) =
            (self.f64()?, self.f64()?, self.f64()?, self.f64()?);
        let kappa_max = match self.u8()? {
            0 => None,
            _ => Some(self.f64()?),
        };
        Ok(Limits {
            v_max,
            v_reverse_max,
            a_max,
            omega_max,
            kappa_max,
            lateral_speed_max: self.f64()?,
            coupled: None,
        })
    }
    pub(crate) fn agents(&mut self) -> Result<Vec<AgentState>, String> {
        let n = self.count(56)?;
        let mut out = Vec::with_capacity(n);
        for _ in 0..n {
            let id = self.u64()?;
            let position = [self.f64()?, self.f64()?];
            let velocity = [self.f64()?, self.f64()?];
            let radius = self.f64()?;
            let h = self.count(16)?;
            let mut history = Vec::with_capacity(h);
            for _ in 0..h {
                history.push([self.f64()?, self.f64()?]);
            }
            out.push(AgentState {
                id,
                position,
                velocity,
                radius,
                history,
            });
        }
        Ok(out)
    }
    pub(crate) fn obstacles(&mut self) -> Result<Vec<Obstacle>, String> {
        let n = self.count(9)?;
        let mut out = Vec::with_capacity(n);
        let mut v = Vec::new();
        for i in 0..n {
            let kind = self.u8()?;
            self.f64s_into(&mut v)?;
            out.push(match (kind, v.as_slice()) {
                (0, &[x, y, radius]) => Obstacle::Circle {
                    center: [x, y],
                    radius,
                },
                (1, &[x0, y0, x1, y1]) => Obstacle::Segment {
                    a: [x0, y0],
                    b: [x1, y1],
                },
                (2, flat) if flat.len() % 2 == 0 => Obstacle::Polygon {
                    vertices: flat.chunks_exact(2).map(|p| [p[0], p[1]]).collect(),
                },
                _ => {
                    return Err(format!(
                        "obstacle {i}: kind {kind} with {} numbers",
                        v.len()
                    ));
                }
            });
        }
        Ok(out)
    }
    pub(crate) fn occupancy(&mut self) -> Result<Option<OccupancyGrid>, String> {
        if self.u8()? == 0 {
            return Ok(None);
        }
        let origin = self.pose()?;
        let resolution = self.f64()?;
        let width = usize::try_from(self.u64()?).map_err(|e| format!("grid width: {e}"))?;
        let height = usize::try_from(self.u64()?).map_err(|e| format!("grid height: {e}"))?;
        let occupied_threshold = i8::from_le_bytes([self.u8()?]);
        let n = self.count(1)?;
        let data = self
            .take(n)?
            .iter()
            .map(|&b| i8::from_le_bytes([b]))
            .collect();
        Ok(Some(OccupancyGrid {
            origin,
            resolution,
            width,
            height,
            data,
            occupied_threshold,
        }))
    }
}

/// Reads one message (without its length) into `buf`; `Ok(false)` at a clean end of input.
pub(crate) fn read_message(
    r: &mut (impl Read + ?Sized),
    buf: &mut Vec<u8>,
) -> std::io::Result<bool> {
    let mut len = [0u8; 4];
    match r.read_exact(&mut len) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(false),
        Err(e) => return Err(e),
    }
    let n = u32::from_le_bytes(len) as usize;
    if n == 0 || n > MAX_MESSAGE_BYTES {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("a message of {n} bytes (limit {MAX_MESSAGE_BYTES})"),
        ));
    }
    buf.clear();
    buf.resize(n, 0);
    r.read_exact(buf)?;
    Ok(true)
}
