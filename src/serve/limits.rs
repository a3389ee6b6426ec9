//! Limits: the bounds the service puts on requests and jobs, all configurable on the
//! command line. Sizes in bytes, counts of facets, steps and targets.

use crate::budget::Budget;

/// The bounds of one service.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Largest request body, bytes.
    pub max_body_bytes: usize,
    /// Most facets (all bodies) a job may have.
    pub max_facets: usize,
    /// Most bodies a job may have.
    pub max_bodies: usize,
    /// Most memory a job may hold (the run's estimate), bytes.
    pub max_job_memory_bytes: u64,
    /// Most memory each of the two caches may hold, bytes: finished runs read for
    /// queries, and scenes built for point queries. The least recently used goes first.
    pub cache_bytes: u64,
    /// Most heavy queries (point irradiance, windows) computed at once; more get 503.
    pub max_heavy_queries: usize,
    /// Longest a heavy query may take before it is answered with 503, seconds.
    pub query_timeout_s: u64,
    /// Most time steps a job may have.
    pub max_steps: usize,
    /// Most facets or locations one query may name.
    pub max_query_targets: usize,
    /// Most values (targets × steps) an on-demand irradiance query may compute.
    pub max_query_values: usize,
    /// Most labels a route plan may take (each up to [`crate::route::BYTES_PER_LABEL`]).
    pub max_route_labels: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_body_bytes: 1 << 20,
            max_facets: 2_000_000,
            max_bodies: 16,
            // Half of what one run may take by default: jobs share the machine with
            // the service's caches and queries.
            max_job_memory_bytes: Budget::machine().max_bytes / 2,
            cache_bytes: 1 << 30,
            max_heavy_queries: std::thread::available_parallelism().map_or(1, |n| n.get()),
            query_timeout_s: 60,
            max_steps: 100_000,
            max_query_targets: 64,
            max_query_values: 1_000_000,
            max_route_labels: crate::route::SearchLimits::default().max_labels,
        }
    }
}

/// Limits the service puts on a route query ([`super::traverse`]).
#[derive(Debug, Clone, Copy)]
pub struct RouteLimits {
    /// The memory the query may hold (a job's budget).
    pub budget: Budget,
    /// Most labels the planner may take.
    pub max_labels: usize,
    /// Most waypoints.
    pub max_waypoints: usize,
}

impl Limits {
    /// The bounds of a route query: the job's memory, the planner's labels and, as for
    /// other queries, the places one query may name (its waypoints).
    pub fn route_limits(&self) -> RouteLimits {
        RouteLimits {
            budget: self.job_budget(),
            max_labels: self.max_route_labels,
            max_waypoints: self.max_query_targets,
        }
    }

    /// The memory budget of one job.
    pub fn job_budget(&self) -> Budget {
        Budget {
            max_bytes: self.max_job_memory_bytes,
            source: "this service's limit per job, --max-job-memory",
        }
    }
}
