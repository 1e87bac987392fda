# Load a studyctl CSV export in R from its Frictionless datapackage.json (column types from the package),
# and print, as JSON, each table's row count, column names and the sum of every numeric column.
# Usage: Rscript read_export.R EXPORT_DIR
# Needs only R and jsonlite (Debian: r-base-core, r-cran-jsonlite). Parquet needs R's arrow package, which
# Debian does not package; read the CSV export (the same tables: both formats read back equal).
suppressPackageStartupMessages(library(jsonlite))
dir <- commandArgs(trailingOnly = TRUE)[1]
pkg <- fromJSON(file.path(dir, "datapackage.json"), simplifyVector = FALSE)
classes <- c(integer = "numeric", number = "numeric", boolean = "logical", string = "character",
             datetime = "character")
out <- list(R = R.version.string)
for (res in pkg$resources) {
  if (res$format != "csv") stop("read_export.R reads the CSV export; ", res$path, " is ", res$format)
  fields <- res$schema$fields
  types <- vapply(fields, function(f) f$type, "")
  names(types) <- vapply(fields, function(f) f$name, "")
  d <- read.csv(file.path(dir, res$path), colClasses = unname(classes[types]), na.strings = "",
                check.names = FALSE, encoding = "UTF-8")
  stopifnot(identical(names(d), names(types)))
  numeric <- names(types)[types %in% c("integer", "number")]
  out[[res$name]] <- list(rows = nrow(d), columns = names(d),
                          sums = lapply(setNames(numeric, numeric), function(n) sum(d[[n]], na.rm = TRUE)))
}
cat(toJSON(out, auto_unbox = TRUE, digits = NA))
