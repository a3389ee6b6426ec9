//! Files: result files served over HTTP with single byte ranges (RFC 9110 §14), so
//! DuckDB, polars and pandas can read Parquet footers and row groups remotely.
//!
//! In: a file path and the request's `Range` header. Out: `200` with the whole file, `206`
//! with `Content-Range` for one satisfiable range, `416` with `Content-Range: bytes */LEN`
//! for an unsatisfiable one; always `Accept-Ranges: bytes`, `Content-Length` and the
//! content type (`application/vnd.apache.parquet`). A header asking for several ranges is
//! answered with the whole file, as the RFC allows. The body is streamed in chunks read
//! on a blocking thread.

use super::reply::{ApiError, ApiResult};
use axum::body::{Body, Bytes, HttpBody};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;
use std::pin::Pin;
use std::task::{Context, Poll};

/// Media type of Parquet files.
pub const PARQUET: &str = "application/vnd.apache.parquet";

/// Bytes read per chunk of a streamed body.
const CHUNK: usize = 1 << 18;

/// What a `Range` header asks of a file of `len` bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wanted {
    /// The whole file (no header, or one this server does not split into parts).
    Whole,
    /// Bytes `start..=end`.
    Part { start: u64, end: u64 },
    /// A range that lies outside the file.
    Unsatisfiable,
}

/// Reads a `Range` header value against a file of `len` bytes.
pub fn wanted(range: Option<&str>, len: u64) -> Wanted {
    let Some(spec) = range.and_then(|r| r.trim().strip_prefix("bytes=")) else {
        return Wanted::Whole;
    };
    if spec.contains(',') {
        return Wanted::Whole;
    }
    let Some((first, last)) = spec.trim().split_once('-') else {
        return Wanted::Whole;
    };
    let number = |s: &str| s.trim().parse::<u64>().ok();
    let (start, end) = match (first.trim().is_empty(), number(first), number(last)) {
        (true, _, Some(suffix)) if suffix > 0 && len > 0 => (len.saturating_sub(suffix), len - 1),
        (true, _, _) => return Wanted::Unsatisfiable,
        (false, Some(start), None) if last.trim().is_empty() => (start, len.saturating_sub(1)),
        (false, Some(start), Some(end)) if end >= start => (start, end.min(len.saturating_sub(1))),
        _ => return Wanted::Whole,
    };
    if start >= len {
        Wanted::Unsatisfiable
    } else {
        Wanted::Part { start, end }
    }
}

/// Serves `path` with `content_type`, honouring a single `Range`.
pub fn serve_file(
    path: &Path,
    content_type: &'static str,
    headers: &HeaderMap,
) -> ApiResult<Response> {
    let mut file = std::fs::File::open(path)
        .map_err(|e| ApiError::internal(format!("opening a result file: {e}")))?;
    let len = file
        .metadata()
        .map_err(|e| ApiError::internal(format!("reading a result file: {e}")))?
        .len();
    let range = headers.get(header::RANGE).and_then(|v| v.to_str().ok());
    let (status, start, count) = match wanted(range, len) {
        Wanted::Whole => (StatusCode::OK, 0, len),
        Wanted::Part { start, end } => (StatusCode::PARTIAL_CONTENT, start, end - start + 1),
        Wanted::Unsatisfiable => {
            let mut e = ApiError::new(
                StatusCode::RANGE_NOT_SATISFIABLE,
                "range_not_satisfiable",
                format!("the file has {len} bytes"),
            )
            .into_response();
            e.headers_mut().insert(
                header::CONTENT_RANGE,
                header_value(&format!("bytes */{len}")),
            );
            return Ok(e);
        }
    };
    file.seek(SeekFrom::Start(start))
        .map_err(|e| ApiError::internal(format!("reading a result file: {e}")))?;
    let mut response = Response::new(Body::new(FileBody::spawn(file, count)));
    *response.status_mut() = status;
    let h = response.headers_mut();
    h.insert(header::CONTENT_TYPE, HeaderValue::from_static(content_type));
    h.insert(header::ACCEPT_RANGES, HeaderValue::from_static("bytes"));
    h.insert(header::CONTENT_LENGTH, header_value(&count.to_string()));
    if status == StatusCode::PARTIAL_CONTENT {
        h.insert(
            header::CONTENT_RANGE,
            header_value(&format!("bytes {start}-{}/{len}", start + count - 1)),
        );
    }
    Ok(response)
}

fn header_value(s: &str) -> HeaderValue {
    HeaderValue::from_str(s).unwrap_or_else(|_| HeaderValue::from_static(""))
}

/// A body fed by a blocking reader thread through a bounded channel.
struct FileBody {
    chunks: tokio::sync::mpsc::Receiver<std::io::Result<Bytes>>,
    remaining: u64,
}

impl FileBody {
    /// Streams `count` bytes of `file` from its current position.
    fn spawn(mut file: std::fs::File, count: u64) -> FileBody {
        let (tx, rx) = tokio::sync::mpsc::channel(4);
        tokio::task::spawn_blocking(move || {
            let mut left = count;
            while left > 0 {
                let mut buf = vec![0; CHUNK.min(left as usize)];
                let chunk = file.read_exact(&mut buf).map(|()| Bytes::from(buf));
                let failed = chunk.is_err();
                if tx.blocking_send(chunk).is_err() || failed {
                    return;
                }
                left -= CHUNK.min(left as usize) as u64;
            }
        });
        FileBody {
            chunks: rx,
            remaining: count,
        }
    }
}

impl HttpBody for FileBody {
    type Data = Bytes;
    type Error = std::io::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<http_body::Frame<Bytes>, std::io::Error>>> {
        if self.remaining == 0 {
            return Poll::Ready(None);
        }
        match self.chunks.poll_recv(cx) {
            Poll::Ready(Some(Ok(bytes))) => {
                self.remaining -= bytes.len() as u64;
                Poll::Ready(Some(Ok(http_body::Frame::data(bytes))))
            }
            Poll::Ready(Some(Err(e))) => Poll::Ready(Some(Err(e))),
            Poll::Ready(None) => Poll::Ready(Some(Err(std::io::Error::new(
                std::io::ErrorKind::UnexpectedEof,
                "the result file ended early",
            )))),
            Poll::Pending => Poll::Pending,
        }
    }

    fn size_hint(&self) -> http_body::SizeHint {
        http_body::SizeHint::with_exact(self.remaining)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_follow_rfc_9110() {
        let part = |start, end| Wanted::Part { start, end };
        assert_eq!(wanted(None, 100), Wanted::Whole);
        assert_eq!(wanted(Some("bytes=0-9"), 100), part(0, 9));
        assert_eq!(wanted(Some("bytes=90-"), 100), part(90, 99));
        assert_eq!(wanted(Some("bytes=-8"), 100), part(92, 99));
        assert_eq!(wanted(Some("bytes=-200"), 100), part(0, 99));
        assert_eq!(wanted(Some("bytes=50-500"), 100), part(50, 99));
        assert_eq!(wanted(Some("bytes=100-"), 100), Wanted::Unsatisfiable);
        assert_eq!(wanted(Some("bytes=-0"), 100), Wanted::Unsatisfiable);
        assert_eq!(wanted(Some("bytes=0-1,5-6"), 100), Wanted::Whole);
        assert_eq!(wanted(Some("bytes=9-3"), 100), Wanted::Whole);
        assert_eq!(wanted(Some("items=0-3"), 100), Wanted::Whole);
        assert_eq!(wanted(Some("bytes=0-"), 0), Wanted::Unsatisfiable);
    }
}
