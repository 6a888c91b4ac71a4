//! A page as a browser shows it: Debian's Chromium, headless, loads a local page (nothing
//! fetched, no error on its console) and screenshots it; the plots are found in the picture
//! by their frames.

use std::path::Path;
use std::process::Command;

/// A screenshot's pixels.
pub struct Shot {
    pub w: usize,
    pub h: usize,
    channels: usize,
    buf: Vec<u8>,
}

/// A plot frame found in a screenshot: x0, x1, y0 (top), y1 (bottom), in pixels.
pub type Frame = (usize, usize, usize, usize);

/// Chromium's screenshot of `page` at `width` × `height`, written to `shot`; panics on a
/// console error or a failed load.
pub fn screenshot(page: &Path, shot: &Path, width: u32, height: u32) -> Shot {
    let profile = tempfile::tempdir().unwrap();
    let run = Command::new("chromium")
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--enable-logging=stderr",
            "--v=0",
            "--hide-scrollbars",
        ])
        .arg(format!("--window-size={width},{height}"))
        .arg(format!("--user-data-dir={}", profile.path().display()))
        .arg(format!("--screenshot={}", shot.display()))
        .arg(format!("file://{}", page.display()))
        .output()
        .expect("chromium runs (apt-get install chromium)");
    let log = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{log}");
    for bad in ["Uncaught", "net::ERR_", "Failed to load"] {
        assert!(!log.contains(bad), "{bad} on the console: {log}");
    }
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(shot).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    Shot {
        w: info.width as usize,
        h: info.height as usize,
        channels: info.color_type.samples(),
        buf,
    }
}

impl Shot {
    pub fn at(&self, x: usize, y: usize) -> (u8, u8, u8) {
        let i = (y * self.w + x) * self.channels;
        (self.buf[i], self.buf[i + 1], self.buf[i + 2])
    }

    /// The plots' frames, top to bottom: their borders (#888, a 1 px line the rasterizer
    /// may spread over two rows of lighter grey) are lines at least 300 px long; a frame is
    /// a top and a bottom line with the same ends, at least 100 px apart.
    pub fn plot_frames(&self) -> Vec<Frame> {
        let border = |p: (u8, u8, u8)| p.0 == p.1 && p.1 == p.2 && p.0 <= 200;
        let mut lines: Vec<(usize, usize, usize)> = Vec::new(); // x0, x1, y
        for y in 0..self.h {
            let mut x = 0;
            while x < self.w {
                let start = x;
                while x < self.w && border(self.at(x, y)) {
                    x += 1;
                }
                if x - start >= 300 {
                    lines.push((start, x, y));
                }
                x += 1;
            }
        }
        // One line per border (an antialiased one covers two rows), then a column's
        // borders in pairs from the top: each plot's top and bottom.
        let same = |a: &(usize, usize, usize), b: &(usize, usize, usize)| {
            a.0.abs_diff(b.0) <= 1 && a.1.abs_diff(b.1) <= 1
        };
        let mut kept: Vec<(usize, usize, usize)> = Vec::new();
        for l in &lines {
            if !kept.iter().any(|k| same(k, l) && k.2.abs_diff(l.2) <= 3) {
                kept.push(*l);
            }
        }
        let mut boxes: Vec<Frame> = Vec::new();
        let mut open: Vec<(usize, usize, usize)> = Vec::new();
        for &(x0, x1, y) in &kept {
            match open
                .iter()
                .position(|o| o.0.abs_diff(x0) <= 1 && o.1.abs_diff(x1) <= 1)
            {
                Some(k) => {
                    let top = open.swap_remove(k);
                    boxes.push((x0, x1, top.2, y));
                }
                None => open.push((x0, x1, y)),
            }
        }
        boxes.retain(|b| b.3 - b.2 >= 100);
        boxes
    }

    /// Pixels inside `frame` within 40 of `colour` in each channel.
    pub fn count_near(&self, frame: Frame, colour: (u8, u8, u8)) -> usize {
        let near = |p: (u8, u8, u8)| {
            p.0.abs_diff(colour.0) < 40
                && p.1.abs_diff(colour.1) < 40
                && p.2.abs_diff(colour.2) < 40
        };
        (frame.2..=frame.3)
            .flat_map(|y| (frame.0..frame.1).map(move |x| (x, y)))
            .filter(|&(x, y)| near(self.at(x, y)))
            .count()
    }
}
