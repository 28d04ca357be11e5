//! Wire types shared by the server, the workers and the command line.
//!
//! Not built yet: the job protocol arrives with the job-server issue. The crate exists so
//! the workspace has its final shape; it deliberately exports nothing.
