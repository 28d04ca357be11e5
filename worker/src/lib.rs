//! The worker that leases DEM jobs over HTTP. Not built yet: see the job-server issue.
