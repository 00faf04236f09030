//! The full-screen terminal view of `chaoscope monitor`: a progress gauge, the live GALI curves
//! (geometric means over sets, log10 against t) of every scheme, and a table of current values.

use std::time::Duration;

use chaoscope_analyzer::analysis::Analysis;
use chaoscope_analyzer::progress::Progress;
use ratatui::DefaultTerminal;
use ratatui::crossterm::event::{self, Event, KeyCode, KeyModifiers};
use ratatui::layout::{Constraint, Layout};
use ratatui::style::{Color, Style};
use ratatui::symbols::Marker;
use ratatui::text::Line;
use ratatui::widgets::{Axis, Block, Chart, Dataset, Gauge, GraphType, Paragraph};

const COLORS: [Color; 6] = [
    Color::Yellow,
    Color::Cyan,
    Color::Magenta,
    Color::Green,
    Color::Red,
    Color::Blue,
];

/// A named, colored curve of (t, log10 GALI) points.
type Curve = (String, Color, Vec<(f64, f64)>);

pub struct TerminalView {
    terminal: DefaultTerminal,
}

impl TerminalView {
    pub fn start() -> std::io::Result<Self> {
        Ok(Self {
            terminal: ratatui::try_init()?,
        })
    }

    /// `q`, Esc or Ctrl+C (raw mode turns Ctrl+C into a key, not a signal).
    pub fn quit_requested(&mut self) -> bool {
        while event::poll(Duration::ZERO).unwrap_or(false) {
            if let Ok(Event::Key(k)) = event::read() {
                let ctrl_c =
                    k.code == KeyCode::Char('c') && k.modifiers.contains(KeyModifiers::CONTROL);
                if ctrl_c || matches!(k.code, KeyCode::Char('q') | KeyCode::Esc) {
                    return true;
                }
            }
        }
        false
    }

    pub fn draw(
        &mut self,
        analysis: &Analysis,
        progress: &Progress,
        frames_lost: u64,
    ) -> std::io::Result<()> {
        let run = analysis.run();
        let report = analysis.report();
        let step = analysis.step();
        // Curves: GALI_j of every scheme (first 6), log10 against t.
        let mut data: Vec<Curve> = Vec::new();
        for (si, s) in run.schemes.iter().take(COLORS.len()).enumerate() {
            let series = analysis.series(si);
            for j in 2..=run.k {
                let pts: Vec<(f64, f64)> = series
                    .iter()
                    .filter(|(t, _)| *t > 0.0)
                    .map(|(t, p)| (*t, p.gali_log10_mean[j - 2]))
                    .collect();
                data.push((format!("{} G{j}", s.name), COLORS[si], pts));
            }
        }
        let (mut ymin, mut ymax) = (0.0f64, 0.0f64);
        for (_, _, pts) in &data {
            for p in pts {
                ymin = ymin.min(p.1);
                ymax = ymax.max(p.1);
            }
        }
        let tmax = analysis.t().max(run.h);
        let title = format!(
            " {} ({}) t = {:.2} / {}  {:.0} steps/s  ETA {}  lost frames {} ",
            run.header.run_name,
            run.header.model,
            analysis.t(),
            run.header.t_final,
            progress.steps_per_second().unwrap_or(0.0),
            progress
                .eta_seconds(step)
                .map_or("?".into(), |e| format!("{e:.0} s")),
            frames_lost
        );
        let mut rows = vec![Line::from(format!(
            "{:<18} {:>8} {:>10} {:>10} {:>10} {:>10}",
            "scheme", "t", "lgGALI2", "lgGALI_k", "lgSALI", "MLE"
        ))];
        for s in &report.schemes {
            rows.push(Line::from(format!(
                "{:<18} {:>8.1} {:>10.3} {:>10.3} {:>10.3} {:>10.6}",
                s.name,
                s.t,
                s.gali.get(2).map_or(f64::NAN, |g| g.log10_mean),
                s.gali.0.last().map_or(f64::NAN, |g| g.1.log10_mean),
                s.sali.map_or(f64::NAN, |v| v.log10_mean),
                s.mle
            )));
        }
        let table_height = (rows.len() as u16 + 2).min(14);
        self.terminal.draw(|f| {
            let [top, mid, bottom] = Layout::vertical([
                Constraint::Length(3),
                Constraint::Min(8),
                Constraint::Length(table_height),
            ])
            .areas(f.area());
            f.render_widget(
                Gauge::default()
                    .block(Block::bordered().title(title.as_str()))
                    .gauge_style(Style::default().fg(Color::Green))
                    .ratio(progress.fraction(step)),
                top,
            );
            let datasets: Vec<Dataset> = data
                .iter()
                .map(|(name, color, pts)| {
                    Dataset::default()
                        .name(name.as_str())
                        .marker(Marker::Braille)
                        .graph_type(GraphType::Line)
                        .style(Style::default().fg(*color))
                        .data(pts)
                })
                .collect();
            let chart = Chart::new(datasets)
                .block(
                    Block::bordered()
                        .title(" log10 GALI_k (geometric mean over sets) vs t; q to detach "),
                )
                .x_axis(Axis::default().bounds([0.0, tmax]).labels([
                    "0".to_string(),
                    format!("{:.0}", tmax / 2.0),
                    format!("{tmax:.0}"),
                ]))
                .y_axis(Axis::default().bounds([ymin - 0.5, ymax + 0.5]).labels([
                    format!("{:.0}", ymin),
                    format!("{:.0}", 0.5 * (ymin + ymax)),
                    format!("{:.0}", ymax),
                ]));
            f.render_widget(chart, mid);
            f.render_widget(
                Paragraph::new(rows.clone()).block(Block::bordered().title(" current values ")),
                bottom,
            );
        })?;
        Ok(())
    }

    pub fn stop(self) -> std::io::Result<()> {
        ratatui::try_restore()
    }
}
