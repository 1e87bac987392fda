# Reference values for studyctl.stats.models (art_anova, mixed_model, ordinal_model), computed in R.
# Run from this folder:  Rscript r_models.R   (writes r_models.json; CI never needs R).
# R 4.2 from Debian with r-cran-lme4, r-cran-lmertest, r-cran-ordinal, r-cran-jsonlite.
#
# ART: the aligned responses are computed step by step here exactly as Wobbrock et al. (2011) describe
# (residual from the full-factorial cell means + the term's effect from marginal means of the observations),
# ranked with average ties; the term is then read from lm on the ranks (type III: full model against the
# model without the term's columns, sum-to-zero contrasts) or, with repeated participants, from the
# likelihood-ratio test of two ML lmer fits with a random intercept per participant. This checks our
# arithmetic and our model fits against R's; it is not ARTool (not in Debian), whose mixed-design F-tests
# use Kenward-Roger df.
suppressPackageStartupMessages({library(lme4); library(ordinal); library(jsonlite)})
options(contrasts = c("contr.sum", "contr.poly"))

terms_of <- function(names) {
  out <- list(); for (k in seq_along(names)) out <- c(out, combn(names, k, simplify = FALSE)); out
}
design <- function(d, names) {
  f <- as.formula(paste("~", paste(names, collapse = "*")))
  X <- model.matrix(f, d); list(X = X, assign = attr(X, "assign"))
}
type3_f <- function(y, X, assign, t) {
  full <- lm.fit(X, y); red <- lm.fit(X[, assign != t, drop = FALSE], y)
  rss_f <- sum(full$residuals^2); rss_r <- sum(red$residuals^2)
  df1 <- full$rank - red$rank; df2 <- length(y) - full$rank
  F <- ((rss_r - rss_f) / df1) / (rss_f / df2)
  list(F = F, df1 = df1, df2 = df2, p = pf(F, df1, df2, lower.tail = FALSE), pes = (rss_r - rss_f) / (rss_r))
}
mixed_lr <- function(y, X, assign, t, subject) {
  Xr <- X[, assign != t, drop = FALSE]
  m1 <- lmer(y ~ 0 + X + (1 | subject), REML = FALSE, control = lmerControl(optimizer = "bobyqa"))
  m0 <- lmer(y ~ 0 + Xr + (1 | subject), REML = FALSE, control = lmerControl(optimizer = "bobyqa"))
  chi2 <- as.numeric(2 * (logLik(m1) - logLik(m0))); df <- ncol(X) - ncol(Xr)
  list(chi2 = chi2, df = df, p = pchisq(chi2, df, lower.tail = FALSE), llf = as.numeric(logLik(m1)))
}
align <- function(d, names, term) {
  cell <- ave(d$y, interaction(d[names], drop = TRUE))
  eff <- rep(0, nrow(d))
  for (k in 0:length(term)) {
    subs <- if (k == 0) list(character(0)) else combn(term, k, simplify = FALSE)
    for (s in subs) {
      sgn <- (-1)^(length(term) - k)
      m <- if (length(s) == 0) rep(mean(d$y), nrow(d)) else ave(d$y, interaction(d[s], drop = TRUE))
      eff <- eff + sgn * m
    }
  }
  (d$y - cell) + eff
}
art <- function(d, names, repeated) {
  ds <- design(d, names); res <- list()
  for (t in seq_along(terms_of(names))) {
    term <- terms_of(names)[[t]]
    r <- rank(align(d, names, term))
    res[[paste(term, collapse = ":")]] <- if (repeated) mixed_lr(r, ds$X, ds$assign, t, d$subject)
                                          else type3_f(r, ds$X, ds$assign, t)
  }
  res
}

out <- list(R = R.version.string, lme4 = as.character(packageVersion("lme4")),
            ordinal = as.character(packageVersion("ordinal")),
            lmerTest = as.character(packageVersion("lmerTest")))

b <- read.csv("art_between.csv", stringsAsFactors = TRUE)
out$art_between <- art(b, c("a", "b"), FALSE)
# The same F-tests from R's own machinery (balanced or not, type III = drop1 on sum contrasts for a model
# whose terms are all tested with the others present): the interaction row of anova(lm) must agree.
b$r_ab <- rank(align(b, c("a", "b"), c("a", "b")))
out$art_between_interaction_anova_lm <- anova(lm(r_ab ~ a * b, data = b))["a:b", "F value"]

m <- read.csv("mixed_unbalanced.csv", stringsAsFactors = TRUE)
m$condition <- factor(m$condition, levels = c("none", "piecewise", "linear", "bio"))
m$group <- factor(m$group, levels = c("novice", "expert"))
out$art_mixed <- art(m, c("group", "condition"), TRUE)
dm <- design(m, c("group", "condition")); mm <- list()
for (t in 1:3) mm[[c("group", "condition", "group:condition")[t]]] <- mixed_lr(m$y, dm$X, dm$assign, t, m$subject)
out$mixed_model <- mm
# For information: lmerTest's Satterthwaite F-tests of the same model (REML), not what studyctl computes.
suppressPackageStartupMessages(library(lmerTest))
sat <- anova(lmerTest::lmer(y ~ group * condition + (1 | subject), data = m))
out$mixed_satterthwaite_info <- list(F = unname(sat[["F value"]]), DenDF = unname(sat[["DenDF"]]),
                                     p = unname(sat[["Pr(>F)"]]), terms = rownames(sat))

l <- read.csv("likert.csv")
l$condition <- factor(l$condition, levels = c("RT", "ES", "EG", "ESG"))
l$y <- factor(l$y, ordered = TRUE)
options(contrasts = c("contr.treatment", "contr.poly"))
fit <- clm(y ~ condition, data = l, control = clm.control(gradTol = 1e-10))
null <- clm(y ~ 1, data = l)
out$ordinal_model <- list(coef = unname(coef(fit)[grep("^condition", names(coef(fit)))]),
                    thresholds = unname(fit$alpha), llf = as.numeric(logLik(fit)),
                    llf0 = as.numeric(logLik(null)),
                    chi2 = as.numeric(2 * (logLik(fit) - logLik(null))), df = 3,
                    p = pchisq(as.numeric(2 * (logLik(fit) - logLik(null))), 3, lower.tail = FALSE))
# Intervals (studyctl.stats.model_intervals).
# Mixed model: REML fit in treatment coding, Wald intervals of the fixed effects.
fit_reml <- lme4::lmer(y ~ group * condition + (1 | subject), data = m, REML = TRUE,
                       control = lmerControl(optimizer = "bobyqa"))
ci <- confint(fit_reml, method = "Wald", parm = "beta_")
out$mixed_coefficients <- list(names = rownames(ci), estimate = unname(fixef(fit_reml)),
                               se = unname(sqrt(diag(as.matrix(vcov(fit_reml))))),
                               low = unname(ci[, 1]), high = unname(ci[, 2]))
# Ordinal model: Wald intervals of the condition log odds ratios (confint.default; confint(clm) would profile).
ci <- confint.default(fit)[grep("^condition", names(coef(fit))), ]
out$ordinal_wald <- list(low = unname(ci[, 1]), high = unname(ci[, 2]))
# ART between subjects: 95 % interval of partial eta squared by inverting the noncentral F in its
# noncentrality (Steiger 2004), eta2p = ncp / (ncp + df1 + df2 + 1).
ncp_at <- function(F, df1, df2, target) {
  if (pf(F, df1, df2) <= target) return(0)
  uniroot(function(l) pf(F, df1, df2, ncp = l) - target, c(0, 1000), tol = 1e-12)$root
}
out$art_between_pes_ci <- lapply(out$art_between, function(r) {
  lo <- ncp_at(r$F, r$df1, r$df2, 0.975); hi <- ncp_at(r$F, r$df1, r$df2, 0.025)
  c(lo / (lo + r$df1 + r$df2 + 1), hi / (hi + r$df1 + r$df2 + 1))
})
writeLines(toJSON(out, auto_unbox = TRUE, digits = NA, pretty = TRUE), "r_models.json")
