//! Routes: the service's single route table, its handlers and the router built from it.
//!
//! In: HTTP requests. Out: JSON documents, result files, or JSON errors. [`table`] lists
//! every route with its method, path and access; the router is built from the same list,
//! and a test compares it with `api/openapi.json`, so the two cannot drift apart. Routes
//! marked [`Access::Write`] need the API token when one is set; the others need it only
//! with `--protect-reads`.

use super::catalogue;
use super::files::{serve_file, PARQUET};
use super::jobs::{Jobs, RESULT_FILES};
use super::points::PointsRequest;
use super::query::{self, FacetsQuery, NearestQuery, ResultCache};
use super::reply::{json, json_errors, ApiError, ApiResult};
use super::scene_input::{check_files, plan, scene_text};
use super::traverse::{self, RouteRequest};
use super::windows::{charging_windows, facet_history, HistoryRows, WindowsQuery};
use super::{App, AppState};
use axum::body::Bytes;
use axum::extract::{DefaultBodyLimit, Path, Query, Request, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::middleware::{from_fn_with_state, map_response, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{delete, get, post, MethodRouter};
use axum::Router;
use serde::Serialize;

/// Whether a route changes state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    Read,
    Write,
}

/// One route: method, path (OpenAPI form, `{id}`), access.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Route {
    pub method: &'static str,
    pub path: &'static str,
    pub access: Access,
}

const fn route(method: &'static str, path: &'static str, access: Access) -> Route {
    Route {
        method,
        path,
        access,
    }
}

/// Every route with its handler.
fn routes() -> Vec<(Route, MethodRouter<AppState>)> {
    use Access::{Read, Write};
    let mut routes = vec![
        (route("GET", "/v1/catalogue", Read), get(list_catalogue)),
        (route("GET", "/v1/jobs", Read), get(list_jobs)),
        (route("POST", "/v1/jobs", Write), post(submit_job)),
        (route("GET", "/v1/jobs/{id}", Read), get(get_job)),
        (route("DELETE", "/v1/jobs/{id}", Write), delete(delete_job)),
        (route("GET", "/v1/jobs/{id}/facets", Read), get(facets)),
        (route("GET", "/v1/jobs/{id}/nearest", Read), get(nearest)),
        (route("GET", "/v1/jobs/{id}/windows", Read), get(windows)),
        (
            route("POST", "/v1/jobs/{id}/irradiance", Read),
            post(irradiance),
        ),
        (
            route("POST", "/v1/jobs/{id}/route", Read),
            post(rover_route),
        ),
    ];
    for (file, path) in RESULT_FILES.iter().zip(RESULT_PATHS) {
        let handler = move |state: State<AppState>, id: Path<String>, headers: HeaderMap| {
            result_file(state, id, headers, file)
        };
        routes.push((route("GET", path, Read), get(handler)));
    }
    routes
}

/// The result-file routes, in the order of [`RESULT_FILES`].
const RESULT_PATHS: [&str; 4] = [
    "/v1/jobs/{id}/summary.parquet",
    "/v1/jobs/{id}/cdf.parquet",
    "/v1/jobs/{id}/geometry.parquet",
    "/v1/jobs/{id}/history.parquet",
];

/// The route table: method, path and access of every route.
pub fn table() -> Vec<Route> {
    routes().into_iter().map(|(r, _)| r).collect()
}

/// The service's router over `app`.
pub fn router(app: AppState) -> Router {
    let protect_reads = app.config.protect_reads;
    let mut router = Router::new();
    for (r, handler) in routes() {
        let guarded = r.access == Access::Write || protect_reads;
        let handler = if guarded {
            handler.route_layer(from_fn_with_state(app.clone(), require_token))
        } else {
            handler
        };
        router = router.route(r.path, handler);
    }
    router
        .layer(DefaultBodyLimit::max(app.config.limits.max_body_bytes))
        .layer(map_response(json_errors))
        .with_state(app)
}

/// Lets a request through when no token is set or it carries `Authorization: Bearer TOKEN`.
async fn require_token(State(app): State<AppState>, request: Request, next: Next) -> Response {
    let Some(token) = app.config.token.as_deref() else {
        return next.run(request).await;
    };
    let given = request
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(bearer_credentials);
    if given.is_some_and(|g| same_bytes(g.trim().as_bytes(), token.as_bytes())) {
        return next.run(request).await;
    }
    let mut response = ApiError::new(
        StatusCode::UNAUTHORIZED,
        "unauthorized",
        "this endpoint needs the header Authorization: Bearer <token>",
    )
    .into_response();
    response
        .headers_mut()
        .insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
    response
}

/// The credentials of an `Authorization` value in the Bearer scheme, whose name is
/// case-insensitive (RFC 9110, section 11.1): `bearer TOKEN` is as good as `Bearer TOKEN`.
fn bearer_credentials(value: &str) -> Option<&str> {
    let (scheme, credentials) = value.split_once(' ')?;
    scheme.eq_ignore_ascii_case("bearer").then_some(credentials)
}

/// Equality that takes the same time wherever the first difference is.
fn same_bytes(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// Runs blocking work off the async threads.
async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> ApiResult<T> + Send + 'static,
) -> ApiResult<T> {
    tokio::task::spawn_blocking(f)
        .await
        .map_err(|e| ApiError::internal(e.to_string()))?
}

/// Runs a heavy query (one that computes or scans per request) under one of the service's
/// permits and its time limit: 503 `busy` when every permit is taken, 503 `query_timeout`
/// when it runs out of time (work already handed to a thread finishes there; its answer
/// is dropped).
async fn heavy<T>(
    app: &App,
    work: impl std::future::Future<Output = ApiResult<T>>,
) -> ApiResult<T> {
    let limits = app.config.limits;
    let _permit = app.heavy.try_acquire().map_err(|_| {
        ApiError::unavailable(
            "busy",
            match limits.max_heavy_queries {
                0 => "this service computes no point or window queries (--max-heavy-queries 0)"
                    .to_string(),
                n => format!(
                    "{n} heavy queries are being computed, the most this service runs at \
                     once; try again shortly"
                ),
            },
        )
    })?;
    let limit = std::time::Duration::from_secs(limits.query_timeout_s);
    tokio::time::timeout(limit, work).await.map_err(|_| {
        ApiError::unavailable(
            "query_timeout",
            format!(
                "the query took longer than {} s, this service's limit: ask for fewer \
                 targets, steps or a shorter time range",
                limits.query_timeout_s
            ),
        )
    })?
}

async fn list_catalogue(State(app): State<AppState>) -> ApiResult<Response> {
    let dir = app.data_dir.clone();
    let listing = blocking(move || Ok(catalogue::list(&dir))).await?;
    Ok(json(&listing))
}

async fn list_jobs(State(app): State<AppState>) -> Response {
    #[derive(Serialize)]
    struct Listing {
        jobs: Vec<super::jobs::JobView>,
    }
    json(&Listing {
        jobs: app.jobs.list(),
    })
}

async fn submit_job(
    State(app): State<AppState>,
    headers: HeaderMap,
    body: Bytes,
) -> ApiResult<Response> {
    let id = Jobs::new_id();
    let content_type = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok());
    let text = scene_text(&app.data_dir, &id, content_type, &body)?;
    let (dir, limits) = (app.data_dir.clone(), app.config.limits);
    let checked = text.clone();
    let planned = blocking(move || plan(&dir, &checked, &limits)).await?;
    let view = app.jobs.submit(id, text, planned.name, &planned.plan)?;
    let mut response = json(&view);
    *response.status_mut() = StatusCode::ACCEPTED;
    if let Ok(location) = HeaderValue::from_str(&format!("/v1/jobs/{}", view.id)) {
        response.headers_mut().insert(header::LOCATION, location);
    }
    Ok(response)
}

async fn get_job(State(app): State<AppState>, Path(id): Path<String>) -> ApiResult<Response> {
    Ok(json(&app.jobs.get(&id)?))
}

async fn delete_job(State(app): State<AppState>, Path(id): Path<String>) -> ApiResult<StatusCode> {
    let jobs = app.clone();
    let job = id.clone();
    blocking(move || jobs.jobs.delete(&job)).await?;
    app.results.forget(&id);
    app.points.forget(&id);
    Ok(StatusCode::NO_CONTENT)
}

async fn result_file(
    State(app): State<AppState>,
    Path(id): Path<String>,
    headers: HeaderMap,
    file: &'static str,
) -> ApiResult<Response> {
    let path = app.jobs.result_dir(&id)?.join(file);
    if !path.is_file() {
        return Err(ApiError::not_found(
            "no_such_result",
            format!("job {id} has no {file} (history needs [output] history = true)"),
        ));
    }
    serve_file(&path, PARQUET, &headers)
}

async fn facets(
    State(app): State<AppState>,
    Path(id): Path<String>,
    Query(q): Query<FacetsQuery>,
) -> ApiResult<Response> {
    let run = ResultCache::get(&app, &id).await?;
    Ok(json(&query::facets(
        &run,
        &q,
        app.config.limits.max_query_targets,
    )?))
}

async fn nearest(
    State(app): State<AppState>,
    Path(id): Path<String>,
    Query(q): Query<NearestQuery>,
) -> ApiResult<Response> {
    let run = ResultCache::get(&app, &id).await?;
    Ok(json(&query::nearest(&run, &q)?))
}

async fn windows(
    State(app): State<AppState>,
    Path(id): Path<String>,
    Query(q): Query<WindowsQuery>,
) -> ApiResult<Response> {
    q.check()?;
    let run = ResultCache::get(&app, &id).await?;
    let body = query::find_body(&run, q.body.as_deref())?;
    query::check_facet(&body.name, body.facets.len(), q.facet)?;
    if !run.dir.join("history.parquet").is_file() {
        return Err(ApiError::conflict(
            "no_history",
            format!("job {id} kept no history: submit the scene with [output] history = true"),
        ));
    }
    let step_s = run.record.duration_s / run.record.plan.steps.max(1) as f64;
    let offset: usize = run
        .bodies
        .iter()
        .take_while(|b| b.name != body.name)
        .map(|b| b.facets.len())
        .sum();
    let rows = HistoryRows {
        global: offset + q.facet,
        total: run.bodies.iter().map(|b| b.facets.len()).sum(),
        steps: run.record.plan.steps,
    };
    let (dir, name, facet) = (run.dir.clone(), body.name.clone(), q.facet as u32);
    let samples = heavy(
        &app,
        blocking(move || {
            facet_history(&dir, &name, facet, rows)
                .map_err(|e| ApiError::internal(format!("reading the history: {e}")))
        }),
    )
    .await?;
    let within = |t: f64| q.from_tdb_s.is_none_or(|f| t >= f) && q.to_tdb_s.is_none_or(|e| t < e);
    let samples: Vec<(f64, f64)> = samples.into_iter().filter(|s| within(s.0)).collect();
    #[derive(Serialize)]
    struct Answer {
        body: String,
        facet: usize,
        threshold_w_m2: f64,
        min_duration_s: f64,
        step_s: f64,
        windows: Vec<super::windows::Window>,
    }
    Ok(json(&Answer {
        body: body.name.clone(),
        facet: q.facet,
        threshold_w_m2: q.threshold_w_m2,
        min_duration_s: q.min_duration_s,
        step_s,
        windows: charging_windows(&samples, step_s, q.threshold_w_m2, q.min_duration_s),
    }))
}

async fn irradiance(
    State(app): State<AppState>,
    Path(id): Path<String>,
    body: Bytes,
) -> ApiResult<Response> {
    let request = PointsRequest::from_body(&body)?;
    let limits = app.config.limits;
    if request.targets.len() > limits.max_query_targets {
        return Err(ApiError::unprocessable(
            "limit_exceeded",
            format!("at most {} targets per query", limits.max_query_targets),
        ));
    }
    let scene = app.jobs.scene(&id)?;
    let answer = heavy(
        &app,
        app.points.ask(&app.data_dir, &id, scene, request, &limits),
    )
    .await?;
    Ok(json(&answer))
}

/// Plans a rover's route, or evaluates one through waypoints, on a job's scene.
async fn rover_route(
    State(app): State<AppState>,
    Path(id): Path<String>,
    body: Bytes,
) -> ApiResult<Response> {
    let request = RouteRequest::from_body(&body)?;
    let (scene, _) = app.jobs.scene(&id)?;
    let limits = app.config.limits.route_limits();
    let dir = app.data_dir.clone();
    let work = blocking(move || {
        let parsed = scene.parse(&dir)?;
        check_files(&dir, &parsed)?;
        traverse::answer(
            Some(&dir),
            &parsed,
            &request,
            &limits,
            &crate::progress::Silent,
        )
    });
    Ok(json(&heavy(&app, work).await?))
}
