//! The one codec module: every bincode call of the project is here. Messages are bincode 2
//! (`config::standard()`: little-endian, variable-length integers) through serde, framed
//! as a 4-byte little-endian payload length followed by the payload. Every decode has a
//! size limit, enforced twice: the frame length is checked before a byte of the payload is
//! read, and bincode's own limit stops a length field inside the payload from claiming more
//! memory than the frame could hold (the 9-byte "allocation bomb" is an error, not an
//! abort).

use serde::Serialize;
use serde::de::DeserializeOwned;
use thiserror::Error;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};

/// Largest message a client may send (bytes of payload).
pub const CLIENT_LIMIT: usize = 64 * 1024;
/// Largest message the server sends (a keyframe of a cut cerebroma is about 150 kB).
pub const SERVER_LIMIT: usize = 8 * 1024 * 1024;

/// A message that could not be encoded, framed or decoded.
#[derive(Debug, Error)]
pub enum CodecError {
    /// The frame announces (or the message needs) more than the limit.
    #[error("message of {len} bytes is over the limit of {limit}")]
    TooLarge {
        /// Its length.
        len: usize,
        /// The limit.
        limit: usize,
    },
    /// Not a message of this protocol.
    #[error("undecodable message: {0}")]
    Decode(String),
    /// Bytes left over after the message.
    #[error("{extra} bytes after the message")]
    Trailing {
        /// How many.
        extra: usize,
    },
    /// Encoding failed (a message the protocol cannot carry).
    #[error("cannot encode: {0}")]
    Encode(String),
    /// The stream failed or ended inside a frame.
    #[error("stream: {0}")]
    Io(#[from] std::io::Error),
}

fn config<const LIMIT: usize>() -> impl bincode::config::Config {
    bincode::config::standard().with_limit::<LIMIT>()
}

/// The payload of `message` (no frame), refused above `LIMIT`.
pub fn encode<T: Serialize, const LIMIT: usize>(message: &T) -> Result<Vec<u8>, CodecError> {
    let bytes = bincode::serde::encode_to_vec(message, config::<LIMIT>())
        .map_err(|e| CodecError::Encode(e.to_string()))?;
    if bytes.len() > LIMIT {
        return Err(CodecError::TooLarge {
            len: bytes.len(),
            limit: LIMIT,
        });
    }
    Ok(bytes)
}

/// `message` as a frame: 4-byte little-endian length, then the payload.
pub fn encode_frame<T: Serialize, const LIMIT: usize>(message: &T) -> Result<Vec<u8>, CodecError> {
    let payload = encode::<T, LIMIT>(message)?;
    let mut frame = Vec::with_capacity(4 + payload.len());
    frame.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    frame.extend_from_slice(&payload);
    Ok(frame)
}

/// Decodes one whole payload (all of it: trailing bytes are an error).
pub fn decode<T: DeserializeOwned, const LIMIT: usize>(payload: &[u8]) -> Result<T, CodecError> {
    if payload.len() > LIMIT {
        return Err(CodecError::TooLarge {
            len: payload.len(),
            limit: LIMIT,
        });
    }
    let (message, used) = bincode::serde::decode_from_slice(payload, config::<LIMIT>())
        .map_err(|e| CodecError::Decode(e.to_string()))?;
    if used != payload.len() {
        return Err(CodecError::Trailing {
            extra: payload.len() - used,
        });
    }
    Ok(message)
}

/// Reads one frame; `None` if the stream ended cleanly before it.
pub async fn read_frame<T: DeserializeOwned, const LIMIT: usize>(
    stream: &mut (impl AsyncRead + Unpin),
) -> Result<Option<T>, CodecError> {
    let mut len = [0u8; 4];
    let mut got = 0;
    while got < 4 {
        let n = stream.read(&mut len[got..]).await?;
        if n == 0 {
            if got == 0 {
                return Ok(None);
            }
            return Err(CodecError::Io(std::io::ErrorKind::UnexpectedEof.into()));
        }
        got += n;
    }
    let len = u32::from_le_bytes(len) as usize;
    if len > LIMIT {
        return Err(CodecError::TooLarge { len, limit: LIMIT });
    }
    let mut payload = vec![0u8; len];
    stream.read_exact(&mut payload).await?;
    decode::<T, LIMIT>(&payload).map(Some)
}

/// Writes one frame.
pub async fn write_frame<T: Serialize, const LIMIT: usize>(
    stream: &mut (impl AsyncWrite + Unpin),
    message: &T,
) -> Result<(), CodecError> {
    let frame = encode_frame::<T, LIMIT>(message)?;
    stream.write_all(&frame).await?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wire::*;

    fn hex(bytes: &[u8]) -> String {
        bytes.iter().map(|b| format!("{b:02x}")).collect()
    }

    fn client(m: &ClientMessage) -> String {
        hex(&encode::<_, CLIENT_LIMIT>(m).unwrap())
    }

    fn server(m: &ServerMessage) -> String {
        hex(&encode::<_, SERVER_LIMIT>(m).unwrap())
    }

    /// One of every message kind, with the bytes it must encode to (checked by hand
    /// against docs/PROTOCOL.md's encoding rules for the first ones).
    fn golden() -> Vec<(String, &'static str)> {
        let spec = FaultSpec {
            fault: Fault::ForceSpike { newtons: 10.0 },
            start: Start::AtTick(300),
            duration_ms: 50,
        };
        let faults = Fault::EXAMPLES;
        let mut all = vec![
            client(&ClientMessage::Hello {
                protocol_version: 1,
                client: "ab".into(),
            }),
            client(&ClientMessage::Subscribe { frame_hz: 30.0 }),
            client(&ClientMessage::Command(Command {
                seq: 7,
                action: Action::Schedule(spec.clone()),
            })),
            client(&ClientMessage::Command(Command {
                seq: 8,
                action: Action::Clear { id: Some(3) },
            })),
            client(&ClientMessage::Command(Command {
                seq: 9,
                action: Action::List,
            })),
        ];
        all.extend(faults.iter().map(|f| {
            client(&ClientMessage::Command(Command {
                seq: 1,
                action: Action::Schedule(FaultSpec {
                    fault: *f,
                    start: Start::Now,
                    duration_ms: 0,
                }),
            }))
        }));
        all.extend([
            server(&ServerMessage::Welcome {
                protocol_version: 1,
                station: "s".into(),
                scene: "liver".into(),
                role: Role::Instructor,
                identity: "ann".into(),
            }),
            server(&ServerMessage::Refused {
                reason: "no".into(),
            }),
            server(&ServerMessage::Ack {
                seq: 7,
                outcome: Outcome::Scheduled { id: 1 },
            }),
            server(&ServerMessage::Ack {
                seq: 8,
                outcome: Outcome::Rejected { reason: "x".into() },
            }),
            server(&ServerMessage::Faults {
                faults: vec![ScheduledFault {
                    id: 1,
                    spec,
                    by: "ann".into(),
                    active: true,
                }],
            }),
            server(&ServerMessage::Metrics(Metrics {
                sim_tick: 1000,
                station_tick: 1002,
                uptime_s: 1.0,
                haptic_rate_hz: 1000.0,
                jitter_p99_ms: 0.02,
                deadline_misses: 0,
                force_n: 2.0,
                faded: false,
                cut_length_mm: 5.5,
                active_points: 480,
                device_connected: true,
            })),
            server(&ServerMessage::Event(Event {
                sim_tick: 5,
                uptime_s: 0.5,
                kind: EventKind::Rupture,
                detail: "r".into(),
            })),
            server(&ServerMessage::Frame(ObserverFrame {
                frame: 2,
                keyframe: 1,
                sim_tick: 40,
                server_time_ns: 300,
                topology: Some(Topology {
                    triangles: vec![[0, 1, 2]],
                    materials: vec![1],
                }),
                origin_m: [0.0, 0.0, 0.0],
                step_m: 1.0,
                positions: vec![[-1, 0, 300]],
                tool: None,
            })),
            server(&ServerMessage::Lesson(LessonPlan {
                name: "l".into(),
                description: String::new(),
                trainee: "ann".into(),
                incisions: vec![PlannedPath {
                    name: "a".into(),
                    points_mm: vec![[0.0, 0.0, 1.0]],
                    depth_mm: 2.0,
                    depth_tolerance_mm: 1.0,
                    deviation_mm: 2.0,
                }],
                no_go: vec![NoGoStructure {
                    name: "v".into(),
                    from_mm: [0.0; 3],
                    to_mm: [0.0; 3],
                    radius_mm: 1.0,
                }],
                warning_n: 2.0,
                critical_n: 4.0,
                time_limit_s: 60.0,
                min_score: 60.0,
            })),
            server(&ServerMessage::Score(LessonScore {
                sim_tick: 300,
                time_s: 1.0,
                rms_deviation_mm: 0.0,
                max_deviation_mm: 0.0,
                rms_depth_error_mm: 0.0,
                max_depth_error_mm: -1.0,
                completed_percent: 50.0,
                strokes: 1,
                economy: 1.0,
                warning_events: 0,
                critical_events: 0,
                peak_force_n: 2.0,
                no_go_contacts: 1,
                no_go_cuts: 0,
                lip_turn_deg: 0.0,
                wounds: 1,
                off_band_area_mm2: 0.0,
                score: 80.0,
                passed: false,
                shortfalls: 2,
            })),
            server(&ServerMessage::Event(Event {
                sim_tick: 5,
                uptime_s: 0.5,
                kind: EventKind::NoGoCut,
                detail: String::new(),
            })),
        ]);
        let expected = [
            "0001026162",
            "010000f041",
            "020700030000204101fb2c0132",
            "0208010103",
            "020902",
            "020100000000",
            "02010001000048420000",
            "020100020000803f0000",
            "02010003000020410000",
            "020100040000803f0000",
            "0201000500000040c80000",
            "020100060000",
            "02010007000080400000",
            "020100080000",
            "020100090000",
            "00010173056c697665720103616e6e",
            "01026e6f",
            "02070001",
            "0208030178",
            "030101030000204101fb2c013203616e6e01",
            "04fbe803fbea03000000000000f03f00007a440ad7a33c0000000040000000b040fbe00101",
            "0505000000000000e03f010172",
            "06020128fb2c01010100010201010000000000000000000000000000803f010100fb580200",
            "07016c0003616e6e0101610100000000000000000000803f000000400000803f000000400101760000000000000000000000000000000000000000000000000000803f00000040000080400000704200007042",
            "08fb2c010000803f000000000000000000000000000080bf00004842010000803f00000000004001000000000001000000000000a0420002",
            "0505000000000000e03f0a00",
        ];
        assert_eq!(all.len(), expected.len());
        all.into_iter().zip(expected).collect()
    }

    #[test]
    fn golden_bytes() {
        let wrong: Vec<String> = golden()
            .into_iter()
            .enumerate()
            .filter(|(_, (got, want))| got != want)
            .map(|(k, (got, want))| format!("message {k}: {got} (pinned {want})"))
            .collect();
        assert!(wrong.is_empty(), "{}", wrong.join("\n"));
    }

    #[test]
    fn a_length_field_claiming_too_much_is_an_error_not_an_allocation() {
        // A Faults message claiming 2^62 entries in 9 bytes.
        let bomb = [3u8, 0xff, 0, 0, 0, 0, 0, 0, 0, 0x40];
        assert!(decode::<ServerMessage, SERVER_LIMIT>(&bomb).is_err());
        // A Hello whose name claims 4 GB.
        let bomb = [0u8, 1, 0xfc, 0xff, 0xff, 0xff, 0xff];
        assert!(decode::<ClientMessage, CLIENT_LIMIT>(&bomb).is_err());
    }

    #[test]
    fn oversized_and_trailing_and_unknown_are_errors() {
        let big = ClientMessage::Hello {
            protocol_version: 1,
            client: "x".repeat(CLIENT_LIMIT),
        };
        assert!(matches!(
            encode::<_, CLIENT_LIMIT>(&big),
            Err(CodecError::TooLarge { .. }) | Err(CodecError::Encode(_))
        ));
        let mut ok =
            encode::<_, CLIENT_LIMIT>(&ClientMessage::Subscribe { frame_hz: 1.0 }).unwrap();
        ok.push(0);
        assert!(matches!(
            decode::<ClientMessage, CLIENT_LIMIT>(&ok),
            Err(CodecError::Trailing { extra: 1 })
        ));
        assert!(decode::<ClientMessage, CLIENT_LIMIT>(&[9]).is_err());
        assert!(decode::<ClientMessage, CLIENT_LIMIT>(&[]).is_err());
    }

    #[tokio::test]
    async fn frames_round_trip_over_a_stream_and_bad_lengths_are_refused() {
        let (mut a, mut b) = tokio::io::duplex(1 << 16);
        let hello = ClientMessage::Hello {
            protocol_version: PROTOCOL_VERSION,
            client: "t".into(),
        };
        write_frame::<_, CLIENT_LIMIT>(&mut a, &hello)
            .await
            .unwrap();
        write_frame::<_, CLIENT_LIMIT>(&mut a, &ClientMessage::Subscribe { frame_hz: 30.0 })
            .await
            .unwrap();
        let got: ClientMessage = read_frame::<_, CLIENT_LIMIT>(&mut b)
            .await
            .unwrap()
            .unwrap();
        assert_eq!(got, hello);
        let got: ClientMessage = read_frame::<_, CLIENT_LIMIT>(&mut b)
            .await
            .unwrap()
            .unwrap();
        assert_eq!(got, ClientMessage::Subscribe { frame_hz: 30.0 });
        // A frame announcing more than the limit is refused before its payload is read.
        AsyncWriteExt::write_all(&mut a, &(CLIENT_LIMIT as u32 + 1).to_le_bytes())
            .await
            .unwrap();
        assert!(matches!(
            read_frame::<ClientMessage, CLIENT_LIMIT>(&mut b).await,
            Err(CodecError::TooLarge { .. })
        ));
        // A clean end between frames is the end, inside one an error.
        drop(a);
        assert!(
            read_frame::<ClientMessage, CLIENT_LIMIT>(&mut b)
                .await
                .unwrap()
                .is_none()
        );
        let (mut a, mut b) = tokio::io::duplex(64);
        AsyncWriteExt::write_all(&mut a, &[5, 0]).await.unwrap();
        drop(a);
        assert!(
            read_frame::<ClientMessage, CLIENT_LIMIT>(&mut b)
                .await
                .is_err()
        );
    }

    proptest::proptest! {
        #[test]
        fn any_bytes_decode_to_a_message_or_an_error(bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..256)) {
            let _ = decode::<ClientMessage, CLIENT_LIMIT>(&bytes);
            let _ = decode::<ServerMessage, SERVER_LIMIT>(&bytes);
        }

        #[test]
        fn quantized_positions_are_within_half_a_step(
            points in proptest::collection::vec(proptest::array::uniform3(-0.3f32..0.3), 1..50)
        ) {
            let (origin, step, codes) = quantize(&points);
            for (p, q) in points.iter().zip(&codes) {
                for c in 0..3 {
                    let back = dequantize_one(q[c], origin[c], step);
                    proptest::prop_assert!((back - p[c]).abs() <= 0.51 * step + 1e-7);
                }
            }
        }
    }
}
