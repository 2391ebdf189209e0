//! ARCL, the LD-60's text protocol (TCP 7171): login, a line parser and a small client.
//!
//! Lines end in `\r\n`. After connecting, the server sends `Enter password:`; the client sends
//! the password line; the server prints a welcome, the command list and `End of commands` (a
//! wrong password closes the connection). Replies and unprompted lines (`EStop pressed`,
//! `EStop relieved`, `DockingState: …`, `Error: …`, `Interrupted: …`) are parsed line by line
//! as `key: value` ([`parse_line`]). ARCL serves status, docking and e-stop: it has no
//! velocity streaming, so the driver only watches it.

use std::io::{self, BufRead, BufReader, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::time::{Duration, Instant};

use thiserror::Error;

/// The server's password prompt.
pub const PASSWORD_PROMPT: &str = "Enter password:";
/// The last line of the login banner.
pub const END_OF_COMMANDS: &str = "End of commands";
/// Longest line ARCL accepts, characters.
pub const MAX_LINE: usize = 5000;

/// One ARCL line, classified.
#[derive(Debug, Clone, PartialEq)]
pub enum ArclLine {
    /// `EStop pressed`.
    EStopPressed,
    /// `EStop relieved`.
    EStopRelieved,
    /// `DockingState: …`.
    DockingState(String),
    /// `Error: …`.
    Error(String),
    /// `Interrupted: …`.
    Interrupted(String),
    /// `CommandError: …` (a bad argument).
    CommandError(String),
    /// `Unknown command <cmd>`.
    UnknownCommand(String),
    /// Any other `key: value` line.
    KeyValue {
        /// The key, as sent.
        key: String,
        /// The value, trimmed.
        value: String,
    },
    /// A line without a `key: ` part.
    Text(String),
}

/// Classifies one line (without its line end).
pub fn parse_line(line: &str) -> ArclLine {
    let line = line.trim_end_matches(['\r', '\n']);
    let trimmed = line.trim();
    if trimmed.eq_ignore_ascii_case("EStop pressed") {
        return ArclLine::EStopPressed;
    }
    if trimmed.eq_ignore_ascii_case("EStop relieved") {
        return ArclLine::EStopRelieved;
    }
    if let Some(cmd) = trimmed.strip_prefix("Unknown command ") {
        return ArclLine::UnknownCommand(cmd.trim().to_owned());
    }
    match trimmed.split_once(": ").or_else(|| {
        trimmed
            .strip_suffix(':')
            .map(|k| (k, ""))
            .filter(|(k, _)| !k.contains(' '))
    }) {
        Some((key, value)) if !key.is_empty() && !key.contains(' ') => {
            let value = value.trim().to_owned();
            match key {
                "DockingState" => ArclLine::DockingState(value),
                "Error" => ArclLine::Error(value),
                "Interrupted" => ArclLine::Interrupted(value),
                "CommandError" => ArclLine::CommandError(value),
                _ => ArclLine::KeyValue {
                    key: key.to_owned(),
                    value,
                },
            }
        }
        _ => ArclLine::Text(trimmed.to_owned()),
    }
}

/// The robot's status, from `status` or `oneLineStatus`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ArclStatus {
    /// `Status:` text.
    pub status: Option<String>,
    /// `BatteryVoltage:`, V.
    pub battery_voltage: Option<f64>,
    /// `Location:` x mm, y mm, heading degrees.
    pub location: Option<(f64, f64, f64)>,
    /// `LocalizationScore:` 0…1.
    pub localization_score: Option<f64>,
    /// `Temperature:` °C (−128: unknown).
    pub temperature: Option<f64>,
}

/// The keys of a status reply, in the order the server sends them.
pub const STATUS_KEYS: [&str; 5] = [
    "Status",
    "BatteryVoltage",
    "Location",
    "LocalizationScore",
    "Temperature",
];

impl ArclStatus {
    /// Takes in one `key: value` pair; `false` if the key is not a status key or the value
    /// does not parse.
    pub fn set(&mut self, key: &str, value: &str) -> bool {
        let number = |s: &str| s.trim().parse::<f64>().ok();
        match key {
            "Status" => self.status = Some(value.trim().to_owned()),
            "BatteryVoltage" => self.battery_voltage = number(value),
            "Location" => {
                let v: Vec<f64> = value.split_whitespace().filter_map(number).collect();
                self.location = (v.len() == 3).then(|| (v[0], v[1], v[2]));
                return self.location.is_some();
            }
            "LocalizationScore" => self.localization_score = number(value),
            "Temperature" => self.temperature = number(value),
            _ => return false,
        }
        true
    }

    /// Whether every key has a value.
    pub fn complete(&self) -> bool {
        self.status.is_some()
            && self.battery_voltage.is_some()
            && self.location.is_some()
            && self.localization_score.is_some()
            && self.temperature.is_some()
    }

    /// Parses a `oneLineStatus` line: the status keys, each followed by `: ` and its value,
    /// on one line.
    pub fn parse_one_line(line: &str) -> Self {
        let mut marks: Vec<(usize, &str)> = STATUS_KEYS
            .iter()
            .filter_map(|k| {
                line.match_indices(&format!("{k}: "))
                    .find(|(i, _)| *i == 0 || line.as_bytes()[i - 1] == b' ')
                    .map(|(i, _)| (i, *k))
            })
            .collect();
        marks.sort();
        let mut status = Self::default();
        for (n, (i, key)) in marks.iter().enumerate() {
            let start = i + key.len() + 2;
            let end = marks.get(n + 1).map_or(line.len(), |m| m.0);
            status.set(key, line[start..end].trim());
        }
        status
    }

    /// The status as the server prints it (`status` reply lines, `\r\n`-terminated).
    pub fn to_lines(&self) -> String {
        let mut out = String::new();
        if let Some(s) = &self.status {
            out += &format!("Status: {s}\r\n");
        }
        if let Some(v) = self.battery_voltage {
            out += &format!("BatteryVoltage: {v:.1}\r\n");
        }
        if let Some((x, y, th)) = self.location {
            out += &format!("Location: {x:.0} {y:.0} {th:.0}\r\n");
        }
        if let Some(v) = self.localization_score {
            out += &format!("LocalizationScore: {v:.3}\r\n");
        }
        if let Some(v) = self.temperature {
            out += &format!("Temperature: {v:.0}\r\n");
        }
        out
    }
}

/// What went wrong on an ARCL connection.
#[derive(Debug, Error)]
pub enum ArclError {
    /// A socket error.
    #[error("socket: {0}")]
    Io(#[from] io::Error),
    /// The server closed the connection (after a wrong password, for one).
    #[error("the ARCL server closed the connection")]
    Closed,
    /// The login did not complete.
    #[error("ARCL login: {0}")]
    Login(String),
    /// No complete reply in time.
    #[error("ARCL: no complete reply to '{0}' in time")]
    Timeout(String),
    /// A line longer than [`MAX_LINE`].
    #[error("ARCL: a line longer than {MAX_LINE} characters")]
    LineTooLong,
}

/// A logged-in ARCL client.
#[derive(Debug)]
pub struct ArclClient {
    reader: BufReader<TcpStream>,
    writer: TcpStream,
    partial: String,
    /// Unprompted lines seen while waiting for a reply, oldest first.
    pending: Vec<ArclLine>,
}

impl ArclClient {
    /// Connects and logs in with `password`, waiting at most `timeout` for each step.
    pub fn connect(
        addr: impl ToSocketAddrs,
        password: &str,
        timeout: Duration,
    ) -> Result<Self, ArclError> {
        let addr = addr
            .to_socket_addrs()?
            .next()
            .ok_or_else(|| ArclError::Login("no address".into()))?;
        let stream = TcpStream::connect_timeout(&addr, timeout)?;
        stream.set_nodelay(true)?;
        stream.set_write_timeout(Some(timeout))?;
        let mut c = Self {
            reader: BufReader::new(stream.try_clone()?),
            writer: stream,
            partial: String::new(),
            pending: Vec::new(),
        };
        let deadline = Instant::now() + timeout;
        c.wait_for(deadline, |l| l.trim() == PASSWORD_PROMPT, "password prompt")?;
        c.send(password)?;
        c.wait_for(deadline, |l| l.trim() == END_OF_COMMANDS, "end of commands")?;
        Ok(c)
    }

    /// Reads lines until one satisfies `done` (lines before it are dropped).
    fn wait_for(
        &mut self,
        deadline: Instant,
        done: impl Fn(&str) -> bool,
        what: &str,
    ) -> Result<(), ArclError> {
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(ArclError::Login(format!("timed out waiting for {what}")));
            }
            if let Some(line) = self.read_raw_line(left)?
                && done(&line)
            {
                return Ok(());
            }
        }
    }

    /// Sends one command line.
    pub fn send(&mut self, command: &str) -> Result<(), ArclError> {
        self.writer.write_all(command.as_bytes())?;
        self.writer.write_all(b"\r\n")?;
        Ok(())
    }

    /// The next line within `timeout`, or `None`. Lines that arrived while a reply was awaited
    /// come first.
    pub fn next_line(&mut self, timeout: Duration) -> Result<Option<ArclLine>, ArclError> {
        if !self.pending.is_empty() {
            return Ok(Some(self.pending.remove(0)));
        }
        Ok(self.read_raw_line(timeout)?.map(|l| parse_line(&l)))
    }

    /// Sends `status` and collects the five status lines; other lines (e-stop, docking, …)
    /// are kept for [`next_line`](Self::next_line).
    pub fn status(&mut self, timeout: Duration) -> Result<ArclStatus, ArclError> {
        self.send("status")?;
        let deadline = Instant::now() + timeout;
        let mut status = ArclStatus::default();
        while !status.complete() {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(ArclError::Timeout("status".into()));
            }
            let Some(line) = self.read_raw_line(left)? else {
                continue;
            };
            match parse_line(&line) {
                ArclLine::KeyValue { key, value } if status.set(&key, &value) => {}
                other => self.pending.push(other),
            }
        }
        Ok(status)
    }

    /// Sends `oneLineStatus` and parses the reply line (the first line holding `Status: `).
    pub fn one_line_status(&mut self, timeout: Duration) -> Result<ArclStatus, ArclError> {
        self.send("oneLineStatus")?;
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(ArclError::Timeout("oneLineStatus".into()));
            }
            let Some(line) = self.read_raw_line(left)? else {
                continue;
            };
            if line.starts_with("Status: ") && line.contains("Location: ") {
                return Ok(ArclStatus::parse_one_line(&line));
            }
            self.pending.push(parse_line(&line));
        }
    }

    /// One raw line (without `\r\n`) within `timeout`.
    fn read_raw_line(&mut self, timeout: Duration) -> Result<Option<String>, ArclError> {
        self.reader
            .get_ref()
            .set_read_timeout(Some(timeout.max(Duration::from_millis(1))))?;
        let mut buf = Vec::new();
        match self.reader.read_until(b'\n', &mut buf) {
            Ok(0) if self.partial.is_empty() => return Err(ArclError::Closed),
            Ok(0) => return Err(ArclError::Closed),
            Ok(_) => {}
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) =>
            {
                // Keep what arrived of a line for the next call.
                self.partial.push_str(&String::from_utf8_lossy(&buf));
                if self.partial.len() > MAX_LINE {
                    return Err(ArclError::LineTooLong);
                }
                return Ok(None);
            }
            Err(e) => return Err(e.into()),
        }
        self.partial.push_str(&String::from_utf8_lossy(&buf));
        if !self.partial.ends_with('\n') {
            // The connection closed mid-line.
            return Err(ArclError::Closed);
        }
        let line = std::mem::take(&mut self.partial);
        if line.len() > MAX_LINE + 2 {
            return Err(ArclError::LineTooLong);
        }
        Ok(Some(line.trim_end_matches(['\r', '\n']).to_owned()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_are_classified() {
        assert_eq!(parse_line("EStop pressed\r\n"), ArclLine::EStopPressed);
        assert_eq!(parse_line("EStop relieved"), ArclLine::EStopRelieved);
        assert_eq!(
            parse_line("DockingState: Docking ForcedState: Unforced"),
            ArclLine::DockingState("Docking ForcedState: Unforced".into())
        );
        assert_eq!(
            parse_line("Error: Cannot find path"),
            ArclLine::Error("Cannot find path".into())
        );
        assert_eq!(
            parse_line("Interrupted: goto x"),
            ArclLine::Interrupted("goto x".into())
        );
        assert_eq!(
            parse_line("CommandError: doTask foo"),
            ArclLine::CommandError("doTask foo".into())
        );
        assert_eq!(
            parse_line("Unknown command frobnicate"),
            ArclLine::UnknownCommand("frobnicate".into())
        );
        assert_eq!(
            parse_line("BatteryVoltage: 26.1"),
            ArclLine::KeyValue {
                key: "BatteryVoltage".into(),
                value: "26.1".into()
            }
        );
        assert_eq!(
            parse_line("Enter password:"),
            ArclLine::Text("Enter password:".into())
        );
        assert_eq!(parse_line("Stopping"), ArclLine::Text("Stopping".into()));
    }

    #[test]
    fn status_lines_and_one_line_status_agree() {
        let mut s = ArclStatus::default();
        for line in [
            "Status: Stopped",
            "BatteryVoltage: 26.1",
            "Location: 1500 -250 90",
            "LocalizationScore: 0.988",
            "Temperature: -128",
        ] {
            let ArclLine::KeyValue { key, value } = parse_line(line) else {
                panic!("{line}");
            };
            assert!(s.set(&key, &value));
        }
        assert!(s.complete());
        assert_eq!(s.location, Some((1500.0, -250.0, 90.0)));
        let one = ArclStatus::parse_one_line(
            "Status: Stopped BatteryVoltage: 26.1 Location: 1500 -250 90 \
             LocalizationScore: 0.988 Temperature: -128",
        );
        assert_eq!(one, s);
        assert!(!ArclStatus::default().set("Location", "1 2"));
        // Status text may contain words: it runs up to the next key.
        let one = ArclStatus::parse_one_line(
            "Status: Going to goal1 BatteryVoltage: 25.0 Location: 0 0 0 \
             LocalizationScore: 1 Temperature: 30",
        );
        assert_eq!(one.status.as_deref(), Some("Going to goal1"));
        let mut round = String::new();
        for l in s.to_lines().lines() {
            round += l;
            round.push(' ');
        }
        assert_eq!(ArclStatus::parse_one_line(round.trim()), s);
    }
}
