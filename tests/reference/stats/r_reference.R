# Reference values from base R for tests/stats. Run from the repository root:
#   Rscript tests/reference/stats/r_reference.R
# Reads inputs.csv (written by make_inputs.py) and writes r_reference.csv with the R version in
# its header lines. Every number is printed with 17 significant digits.
args <- commandArgs(trailingOnly = FALSE)
here <- dirname(normalizePath(sub("--file=", "", args[grep("--file=", args)])))
inp <- read.csv(file.path(here, "inputs.csv"))
get <- function(ds, g) inp$value[inp$dataset == ds & inp$group == g]
groups <- function(ds) {
  gs <- unique(inp$group[inp$dataset == ds])
  setNames(lapply(gs, function(g) get(ds, g)), gs)
}
out <- data.frame(case = character(), key = character(), value = character())
put <- function(case, key, value) {
  out[nrow(out) + 1, ] <<- list(case, key, formatC(as.numeric(value), digits = 17, format = "g"))
}
sw <- function(...) suppressWarnings(...)

# --- Wilcoxon rank-sum (wilcox.test) ---
rs <- list(
  mw_a = list(get("mw_a", "x"), get("mw_a", "y")),
  mw_sep = list(get("mw_sep", "x"), get("mw_sep", "y")),
  mw_ties = list(get("mw_ties", "x"), get("mw_ties", "y")),
  mw_big = list(get("mw_big", "x"), get("mw_big", "y")),
  r_example = list(c(0.80, 0.83, 1.89, 1.04, 1.45, 1.38, 1.91, 1.64, 0.73, 1.46), c(1.15, 0.88, 0.90, 0.74, 1.21)),
  case12 = list(1:10, seq(2, 24, 2)),
  sep10 = list(11:20, 1:10),
  sep50 = list(51:100, 1:50),
  n1 = list(5, 1:4),
  heavy = list(rep(1:5, c(163, 81, 40, 6, 2)), rep(1:5, c(1007, 362, 99, 27, 13)))
)
for (nm in names(rs)) {
  x <- rs[[nm]][[1]]; y <- rs[[nm]][[2]]
  for (alt in c("two.sided", "less", "greater")) {
    for (cc in c(TRUE, FALSE)) {
      r <- sw(wilcox.test(x, y, alternative = alt, correct = cc))
      tag <- paste0(nm, ":", alt, ":correct=", cc)
      put(tag, "statistic", r$statistic); put(tag, "pvalue", r$p.value)
    }
    r <- sw(wilcox.test(x, y, alternative = alt, exact = FALSE, correct = TRUE))
    put(paste0(nm, ":", alt, ":asymptotic"), "pvalue", r$p.value)
  }
}

# --- Wilcoxon signed-rank ---
sr <- list(
  sr_a = get("sr_a", "d"),
  sr_ties = get("sr_ties", "d"),
  r_paired = c(1.83, 0.50, 1.62, 2.48, 1.68, 1.88, 1.55, 3.06, 1.30) - c(0.878, 0.647, 0.598, 2.05, 1.06, 1.29, 1.06, 3.14, 1.29),
  tie5 = c(1, 1, 2, 3, 4),
  zero5 = c(0, 1, 2, 3, 4),
  pos55 = 1:55,
  pos20 = 1:20
)
for (nm in names(sr)) {
  for (alt in c("two.sided", "less", "greater")) {
    for (cc in c(TRUE, FALSE)) {
      r <- sw(wilcox.test(sr[[nm]], alternative = alt, correct = cc))
      tag <- paste0(nm, ":", alt, ":correct=", cc)
      put(tag, "statistic", r$statistic); put(tag, "pvalue", r$p.value)
    }
  }
  if (!any(sr[[nm]] == 0) && !any(duplicated(abs(sr[[nm]])))) {
    r <- wilcox.test(sr[[nm]], exact = TRUE)
    put(paste0(nm, ":two.sided:exact"), "pvalue", r$p.value)
  }
}
# exact critical values: largest w with P(V <= w) <= alpha/2 (two-sided) or alpha (one-sided)
for (n in 6:30) {
  w <- 0:(n * (n + 1) / 2)
  put(paste0("wcrit:", n), "two.sided_0.05", max(w[psignrank(w, n) <= 0.025]))
  put(paste0("wcrit:", n), "one.sided_0.05", max(w[psignrank(w, n) <= 0.05]))
  ok <- w[psignrank(w, n) <= 0.005]
  put(paste0("wcrit:", n), "two.sided_0.01", if (length(ok)) max(ok) else NA)
}

# --- Kruskal-Wallis and Dunn (z and p written out from the formula in R) ---
kw <- list(kw_a = groups("kw_a"), kw_likert = groups("kw_likert"), warp = groups("warp"),
           case18a = list(c(1, 1, 1), c(2, 2, 2), c(2, 2)), case18b = list(c(1, 3, 5, 7, 9), c(2, 4, 6, 8, 10)),
           singletons = list(1, 2, 3))
for (nm in names(kw)) {
  g <- kw[[nm]]
  r <- kruskal.test(g)
  put(paste0("kw:", nm), "statistic", r$statistic); put(paste0("kw:", nm), "pvalue", r$p.value)
  x <- unlist(g); f <- rep(seq_along(g), sapply(g, length))
  rk <- rank(x); N <- length(x); tt <- table(x)
  s2 <- N * (N + 1) / 12 - sum(tt^3 - tt) / (12 * (N - 1))
  mr <- tapply(rk, f, mean); nn <- sapply(g, length)
  k <- length(g); z <- c(); p <- c()
  for (i in 1:(k - 1)) for (j in (i + 1):k) {
    zz <- (mr[i] - mr[j]) / sqrt(s2 * (1 / nn[i] + 1 / nn[j]))
    z <- c(z, zz); p <- c(p, 2 * pnorm(-abs(zz)))
  }
  for (m in seq_along(z)) {
    put(paste0("dunn:", nm), paste0("z", m), z[m]); put(paste0("dunn:", nm), paste0("p", m), p[m])
    for (meth in c("holm", "bonferroni", "BH")) put(paste0("dunn:", nm), paste0(meth, m), p.adjust(p, meth)[m])
    put(paste0("dunn:", nm), paste0("tukey", m), ptukey(sqrt(2) * abs(z[m]), k, Inf, lower.tail = FALSE))
  }
}

# --- one-way ANOVA and Tukey HSD ---
for (nm in c("anova_5x12", "anova_unequal", "warp", "kw_a")) {
  g <- groups(nm)
  d <- data.frame(y = unlist(g), f = factor(rep(names(g), sapply(g, length)), levels = names(g)))
  r <- oneway.test(y ~ f, d, var.equal = TRUE)
  put(paste0("anova:", nm), "statistic", r$statistic); put(paste0("anova:", nm), "pvalue", r$p.value)
  fit <- aov(y ~ f, d)
  tk <- TukeyHSD(fit)$f
  for (m in seq_len(nrow(tk))) for (col in c("diff", "lwr", "upr", "p adj")) put(paste0("tukey:", nm), paste0(col, m), tk[m, col])
  d2 <- d; d2$y <- d2$y + 1e9
  put(paste0("anova:", nm), "statistic_offset1e9", oneway.test(y ~ f, d2, var.equal = TRUE)$statistic)
}

# --- studentized range: ptukey upper tail and qtukey ---
grid <- expand.grid(q = c(0.5, 1, 2, 3.5, 5, 8), k = c(2, 3, 5, 10), df = c(2, 5, 10, 30, 120, Inf))
for (i in seq_len(nrow(grid))) {
  put(sprintf("ptukey:%g:%g:%g", grid$q[i], grid$k[i], grid$df[i]), "sf", ptukey(grid$q[i], grid$k[i], grid$df[i], lower.tail = FALSE))
}
for (k in c(3, 5, 10)) for (df in c(10, 55)) put(sprintf("qtukey:0.95:%g:%g", k, df), "q", qtukey(0.95, k, df))

# --- Friedman ---
g <- groups("rm_4x10")
m <- do.call(cbind, g)
r <- friedman.test(m)
put("friedman:rm_4x10", "statistic", r$statistic); put("friedman:rm_4x10", "pvalue", r$p.value)

# --- Wilson intervals (formula) ---
for (xn in list(c(0, 10), c(10, 10), c(81, 263), c(15, 148), c(1, 29), c(50, 60), c(30, 60), c(47, 60))) {
  x <- xn[1]; n <- xn[2]; z <- qnorm(0.975)
  ctr <- (x + z^2 / 2) / (n + z^2); hw <- z * sqrt(x * (n - x) / n + z^2 / 4) / (n + z^2)
  put(sprintf("wilson:%d:%d", x, n), "lower", max(0, ctr - hw)); put(sprintf("wilson:%d:%d", x, n), "upper", min(1, ctr + hw))
}

con <- file(file.path(here, "r_reference.csv"), "w")
writeLines(paste0("# ", R.version.string), con)
writeLines(paste0("# generated by r_reference.R from inputs.csv on ", format(Sys.Date())), con)
write.csv(out, con, row.names = FALSE, quote = FALSE)
close(con)
cat("wrote", nrow(out), "values\n")
